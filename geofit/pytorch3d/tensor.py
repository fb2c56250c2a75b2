"""A numpy array that remembers how it was made: the tape behind ``loss.backward()``.

PyTorch3D's tutorials write their training loops with torch tensors: a parameter created with
``requires_grad=True``, losses that add up (``loss_chamfer * w + loss_edge * w``), and
``loss.backward()`` filling ``parameter.grad``. :class:`Tensor` reproduces exactly that much over
numpy, **without a general autodiff framework**: every differentiable operation of
:mod:`geofit.pytorch3d` (the losses, the sampling, ``offset_verts``, the soft renderers) records
its inputs and one vector-Jacobian product (vjp) closure built from geofit's own analytic
gradients; :meth:`Tensor.backward` runs these closures in reverse topological order and sums the
gradients that reach each leaf.

The arithmetic recorded on the tape is the one the tutorials use: ``+``, ``-``, ``*``, ``/``
(between tensors and with constants, with numpy broadcasting), unary ``-``, ``** p`` for a
constant ``p``, ``abs``, ``sum``, ``mean``, indexing and slicing, ``reshape``/``view``,
``squeeze``/``unsqueeze`` and ``clone``. Any other numpy function applied to a tensor that
requires a gradient raises a ``TypeError`` saying so (instead of silently dropping the gradient);
on tensors without a gradient every numpy function works and returns a plain result.

Values are float64 (torch's default is float32): geofit's gradients are exact in float64 and the
tests compare the tape with the analytic ``(value, grad)`` functions to 1e-10.

Examples
--------
>>> import numpy as np
>>> from geofit.pytorch3d.tensor import Parameter
>>> x = Parameter(np.array([1.0, 2.0, 3.0]))
>>> loss = ((x * 2.0 - 1.0) ** 2).mean()
>>> loss.backward()
>>> x.grad.numpy()  # d/dx mean((2x - 1)^2) = 4 (2x - 1) / 3
array([1.33333333, 4.        , 6.66666667])
"""
from __future__ import annotations

import contextlib
import numbers
import threading
from collections import namedtuple
from collections.abc import Callable, Sequence

import numpy as np

__all__ = [
    "Parameter",
    "Size",
    "Tensor",
    "arange",
    "as_tensor",
    "cat",
    "chunk",
    "default_rng",
    "device",
    "eye",
    "from_numpy",
    "full_like",
    "is_tensor",
    "rand",
    "randn",
    "split",
    "manual_seed",
    "stack",
    "full",
    "is_grad_enabled",
    "linspace",
    "no_grad",
    "ones",
    "ones_like",
    "randint",
    "randperm",
    "record",
    "sigmoid",
    "tensor",
    "zeros",
    "zeros_like",
]

#: ``values, indices`` of ``Tensor.max(dim)`` / ``Tensor.min(dim)`` (torch's return type).
MaxMin = namedtuple("MaxMin", ["values", "indices"])


class Size(tuple):
    """A tensor's shape: a tuple with ``numel()`` (``torch.Size``)."""

    def numel(self) -> int:
        return int(np.prod(self, dtype=np.int64))

    def __getitem__(self, index):
        out = tuple.__getitem__(self, index)
        return Size(out) if isinstance(index, slice) else out


class _GradMode(threading.local):
    enabled = True


_MODE = _GradMode()


def is_grad_enabled() -> bool:
    """False inside a :func:`no_grad` block."""
    return _MODE.enabled


@contextlib.contextmanager
def no_grad():
    """Context manager: operations inside record nothing on the tape (``torch.no_grad``)."""
    prev = _MODE.enabled
    _MODE.enabled = False
    try:
        yield
    finally:
        _MODE.enabled = prev


def _data(x):
    """The numpy value of a Tensor, or ``x`` itself."""
    return x.data if isinstance(x, Tensor) else x


def _comparison(ufunc):
    """A comparison operator of :class:`Tensor`: ``ufunc`` (``np.less``, ...) on the values of
    ``self`` and ``other`` (a tensor, an array or a number), as a new tensor without gradient."""
    def compare(self, other):
        return Tensor(ufunc(self.data, _data(other)))

    return compare


def _unbroadcast(g: np.ndarray, shape: tuple) -> np.ndarray:
    """Sum ``g`` over the axes that numpy broadcasting added or stretched to reach its shape."""
    if g.shape == shape:
        return g
    lead = g.ndim - len(shape)
    if lead > 0:
        g = g.sum(axis=tuple(range(lead)))
    axes = tuple(i for i, s in enumerate(shape) if s == 1 and g.shape[i] != 1)
    if axes:
        g = g.sum(axis=axes, keepdims=True)
    return g.reshape(shape)


def _tracks(*xs) -> bool:
    return _MODE.enabled and any(isinstance(x, Tensor) and x.requires_grad for x in xs)


# the numpy ufuncs that the tape records when an operand requires a gradient
_RECORDED_UFUNCS = {
    np.add: "__add__", np.subtract: "__sub__", np.multiply: "__mul__",
    np.true_divide: "__truediv__", np.negative: "__neg__", np.power: "__pow__",
    np.absolute: "abs",
}


class Tensor:
    """A numpy array with an optional gradient record (the tutorials' ``torch.Tensor``).

    Parameters
    ----------
    data : array_like
        The value; stored as a numpy array (floats as float64).
    requires_grad : bool
        Whether :meth:`backward` should compute ``.grad`` for this tensor (a *leaf*).

    Attributes
    ----------
    data : numpy.ndarray
        The value (``.numpy()`` returns it).
    grad : Tensor or None
        The accumulated gradient of a leaf after :meth:`backward` (``None`` before, and after
        an optimizer's ``zero_grad()``).
    requires_grad : bool
        True for leaves created with ``requires_grad=True`` and for every result computed from
        one while gradients are enabled.

    Notes
    -----
    ``device=`` arguments, ``.to(device)``, ``.cpu()`` and ``.cuda()``-free code paths are
    accepted and ignored: everything runs on the CPU. ``.numpy()`` on a tensor that requires a
    gradient raises, as in torch: call ``.detach()`` first.
    """

    __slots__ = ("data", "requires_grad", "grad", "_parents", "_vjp", "__weakref__")
    __array_priority__ = 1000

    def __init__(self, data, requires_grad: bool = False, *, _parents=(), _vjp=None):
        arr = np.asarray(_data(data))
        if arr.dtype.kind in "fc" and arr.dtype != np.float64:
            arr = arr.astype(np.float64)
        elif arr.dtype.kind in "iu" and requires_grad:
            raise TypeError("requires_grad: only floating point tensors can require gradients "
                            f"(got dtype {arr.dtype})")
        self.data = arr
        self.requires_grad = bool(requires_grad)
        self.grad = None
        self._parents = tuple(_parents)
        self._vjp = _vjp

    # ------------------------------------------------------------------ recording
    @classmethod
    def _record(cls, value, parents: Sequence, vjp: Callable) -> Tensor:
        """A result of ``parents`` with ``vjp(g) -> tuple of gradients (None = no gradient)``.

        Records nothing (a constant tensor) when no parent requires a gradient or inside
        :func:`no_grad`.
        """
        if not _tracks(*parents):
            return Tensor(value)
        parents = tuple(parents)
        return Tensor(value, True, _parents=parents, _vjp=vjp)

    @property
    def is_leaf(self) -> bool:
        return self._vjp is None

    def backward(self, gradient=None) -> None:
        """Accumulate ``d self / d leaf`` into the ``.grad`` of every leaf that requires it.

        Parameters
        ----------
        gradient : array_like, optional
            ``dL/d self`` (shape of ``self``); default 1 for a one-element tensor.

        Raises
        ------
        RuntimeError
            If the tensor does not require a gradient, or has more than one element and no
            ``gradient`` is given.
        """
        if not self.requires_grad:
            raise RuntimeError("backward: this tensor does not require a gradient (no parameter "
                               "with requires_grad=True went into it, or it was computed under "
                               "no_grad())")
        if gradient is None:
            if self.data.size != 1:
                raise RuntimeError(f"backward: a gradient is needed for a tensor of shape "
                                   f"{self.data.shape} (only one-element tensors default to 1)")
            g = np.ones_like(self.data, dtype=np.float64)
        else:
            g = np.broadcast_to(np.asarray(_data(gradient), np.float64), self.data.shape)
        # reverse post-order of a depth-first walk = every node before the nodes it came from
        order, seen = [], set()
        stack = [(self, False)]
        while stack:  # loop over the nodes of the recorded graph, not over array elements
            node, expanded = stack.pop()
            if expanded:
                order.append(node)
                continue
            if id(node) in seen:
                continue
            seen.add(id(node))
            stack.append((node, True))
            stack.extend((p, False) for p in node._parents
                         if p.requires_grad and id(p) not in seen)
        grads = {id(self): g}
        for node in reversed(order):
            g = grads.pop(id(node), None)
            if g is None:
                continue
            if node._vjp is None:  # a leaf
                node.grad = Tensor(g) if node.grad is None else Tensor(node.grad.data + g)
                continue
            for p, pg in zip(node._parents, node._vjp(g)):
                if pg is None or not p.requires_grad:
                    continue
                pg = np.asarray(pg, np.float64)
                if pg.shape != p.data.shape:
                    pg = _unbroadcast(pg, p.data.shape)
                k = id(p)
                grads[k] = pg if k not in grads else grads[k] + pg

    def requires_grad_(self, requires_grad: bool = True) -> Tensor:
        """Make this (leaf) tensor require a gradient, in place."""
        if not self.is_leaf:
            raise RuntimeError("requires_grad_: only leaf tensors can change requires_grad")
        if requires_grad and self.data.dtype.kind not in "fc":
            raise TypeError("requires_grad_: only floating point tensors can require gradients")
        self.requires_grad = bool(requires_grad)
        return self

    # ------------------------------------------------------------------ torch conveniences
    def detach(self) -> Tensor:
        """The same value without gradient history (shares memory, as torch)."""
        return Tensor(self.data)

    def clone(self) -> Tensor:
        """A copy; the gradient flows through it."""
        return Tensor._record(self.data.copy(), (self,), lambda g: (g,))

    def cpu(self) -> Tensor:
        """Itself: everything is on the CPU."""
        return self

    def to(self, *args, **kwargs) -> Tensor:
        """Itself (devices are ignored); a numpy dtype among the arguments casts the value."""
        dtype = kwargs.get("dtype")
        for a in args:
            if isinstance(a, (type, np.dtype)):
                dtype = a
        if dtype is None or np.dtype(dtype) == self.data.dtype:
            return self
        return Tensor(self.data.astype(dtype))

    def numpy(self) -> np.ndarray:
        """The value as a numpy array (shares memory).

        Raises
        ------
        RuntimeError
            If the tensor requires a gradient (as torch): use ``.detach().numpy()``.
        """
        if self.requires_grad:
            raise RuntimeError("numpy: the tensor requires a gradient; use "
                               "tensor.detach().numpy()")
        return self.data

    def item(self):
        return self.data.item()

    def tolist(self):
        return self.data.tolist()

    @property
    def shape(self) -> Size:
        return Size(self.data.shape)

    @property
    def ndim(self) -> int:
        return self.data.ndim

    @property
    def dtype(self):
        return self.data.dtype

    @property
    def device(self) -> str:
        return "cpu"

    def size(self, dim: int | None = None):
        """The shape (torch's ``size()``), or one of its entries."""
        return Size(self.data.shape) if dim is None else self.data.shape[dim]

    def dim(self) -> int:
        return self.data.ndim

    def numel(self) -> int:
        return int(self.data.size)

    def __len__(self) -> int:
        return len(self.data)

    def __iter__(self):
        for i in range(len(self.data)):  # loop over the first axis, as torch
            yield self[i]

    def __array__(self, dtype=None, copy=None):
        if dtype is None:
            return self.data
        return self.data.astype(dtype, copy=False)

    def __float__(self) -> float:
        return float(self.data.item())  # one element of any shape, as torch

    def __int__(self) -> int:
        return int(self.data.item())

    def __index__(self) -> int:
        return self.data.__index__()

    def __bool__(self) -> bool:
        return bool(self.data)

    def __format__(self, spec: str) -> str:
        if self.data.ndim == 0:
            return format(self.data.item(), spec)
        return format(str(self), spec)

    def __repr__(self) -> str:
        body = np.array2string(self.data, separator=", ", prefix="tensor(")
        extra = ", requires_grad=True" if self.requires_grad else ""
        return f"tensor({body}{extra})"

    __hash__ = object.__hash__

    # ------------------------------------------------------------------ recorded arithmetic
    def _binary(self, other, fn, vjp_self, vjp_other):
        o = _data(other)
        value = fn(self.data, o)
        return Tensor._record(value, (self, other) if isinstance(other, Tensor) else (self,),
                              lambda g: (vjp_self(g, self.data, o), vjp_other(g, self.data, o)))

    def __add__(self, other):
        return self._binary(other, np.add, lambda g, a, b: g, lambda g, a, b: g)

    def __radd__(self, other):
        return self.__add__(other)

    def __sub__(self, other):
        return self._binary(other, np.subtract, lambda g, a, b: g, lambda g, a, b: -g)

    def __rsub__(self, other):
        return (-self).__add__(other)

    def __mul__(self, other):
        return self._binary(other, np.multiply, lambda g, a, b: g * b, lambda g, a, b: g * a)

    def __rmul__(self, other):
        return self.__mul__(other)

    def __truediv__(self, other):
        return self._binary(other, np.true_divide, lambda g, a, b: g / b,
                            lambda g, a, b: -g * a / (b * b))

    def __rtruediv__(self, other):
        o = _data(other)
        a = self.data
        return Tensor._record(o / a, (self,), lambda g: (-g * o / (a * a),))

    def __neg__(self):
        return Tensor._record(-self.data, (self,), lambda g: (-g,))

    def __pos__(self):
        return self

    def __pow__(self, p):
        if isinstance(p, Tensor):
            if p.requires_grad and _MODE.enabled:
                raise TypeError("**: the tape records powers with a constant exponent only")
            p = p.data
        a = self.data
        if isinstance(p, numbers.Number) and p == 2:
            return Tensor._record(a * a, (self,), lambda g: (2.0 * g * a,))
        return Tensor._record(a ** p, (self,), lambda g: (g * p * a ** (p - 1),))

    def __rpow__(self, base):
        c = _data(base)
        v = np.power(c, self.data.astype(np.float64))
        return Tensor._record(v, (self,), lambda g: (g * v * np.log(c),))

    def abs(self) -> Tensor:
        """``|x|`` (gradient ``sign(x)``, 0 at 0 as torch)."""
        a = self.data
        return Tensor._record(np.abs(a), (self,), lambda g: (g * np.sign(a),))

    __abs__ = abs

    def sum(self, dim=None, keepdim: bool = False) -> Tensor:
        """Sum over ``dim`` (an int or tuple; None: all)."""
        shape = self.data.shape
        value = self.data.sum(axis=dim, keepdims=keepdim)

        def vjp(g):
            if dim is not None and not keepdim:
                g = np.expand_dims(g, dim)
            return (np.broadcast_to(g, shape),)

        return Tensor._record(value, (self,), vjp)

    def mean(self, dim=None, keepdim: bool = False) -> Tensor:
        """Mean over ``dim`` (an int or tuple; None: all)."""
        total = self.sum(dim, keepdim)
        n = self.data.size // max(total.data.size, 1)
        return total / n if n else total

    def __getitem__(self, index):
        index = _data(index)
        if isinstance(index, tuple):
            index = tuple(list(i) if isinstance(i, range) else _data(i) for i in index)
            ints = [isinstance(i, (int, np.integer)) for i in index]
            arrays = [isinstance(i, (list, np.ndarray)) and np.ndim(i) > 0 for i in index]
            if any(ints) and any(arrays) and not any(i is None for i in index):
                # torch applies integer indices as basic indexing (numpy would broadcast them
                # with the arrays and move the result's axes to the front): do them first
                first = tuple(i if k else (Ellipsis if i is Ellipsis else slice(None))
                              for i, k in zip(index, ints))
                return self[first][tuple(i for i, k in zip(index, ints) if not k)]
        elif isinstance(index, range):
            index = list(index)
        shape = self.data.shape
        value = self.data[index]

        basic = all(isinstance(i, (int, np.integer, slice)) or i is None or i is Ellipsis
                    for i in (index if isinstance(index, tuple) else (index,)))

        def vjp(g):
            out = np.zeros(shape)
            if basic:
                out[index] = g
            else:
                np.add.at(out, index, g)  # repeated fancy indices add up
            return (out,)

        return Tensor._record(value, (self,), vjp)

    def reshape(self, *shape) -> Tensor:
        if len(shape) == 1 and isinstance(shape[0], (tuple, list)):
            shape = tuple(shape[0])
        old = self.data.shape
        return Tensor._record(self.data.reshape(shape), (self,), lambda g: (g.reshape(old),))

    view = reshape

    def squeeze(self, dim=None) -> Tensor:
        if dim is not None and self.data.shape[dim] != 1:
            return self
        old = self.data.shape
        return Tensor._record(np.squeeze(self.data, axis=dim), (self,),
                              lambda g: (g.reshape(old),))

    def unsqueeze(self, dim: int) -> Tensor:
        old = self.data.shape
        return Tensor._record(np.expand_dims(self.data, dim), (self,),
                              lambda g: (g.reshape(old),))

    def unbind(self, dim: int = 0) -> tuple:
        """The slices along ``dim`` (each keeps the gradient)."""
        n = self.data.shape[dim]
        return tuple(self[(slice(None),) * (dim % self.data.ndim) + (i,)] for i in range(n))

    def sigmoid(self) -> Tensor:
        """``1 / (1 + exp(-x))`` (gradient ``s (1 - s)``)."""
        a = self.data
        s = np.empty_like(a)
        pos = a >= 0
        s[pos] = 1.0 / (1.0 + np.exp(-a[pos]))
        e = np.exp(a[~pos])
        s[~pos] = e / (1.0 + e)  # no overflow for large negative inputs
        return Tensor._record(s, (self,), lambda g: (g * s * (1.0 - s),))

    def sqrt(self) -> Tensor:
        """``sqrt(x)`` (gradient ``1 / (2 sqrt(x))``)."""
        r = np.sqrt(self.data)
        return Tensor._record(r, (self,), lambda g: (g * 0.5 / r,))

    def exp(self) -> Tensor:
        """``exp(x)``."""
        e = np.exp(self.data)
        return Tensor._record(e, (self,), lambda g: (g * e,))

    def sin(self) -> Tensor:
        """``sin(x)``."""
        a = self.data
        return Tensor._record(np.sin(a), (self,), lambda g: (g * np.cos(a),))

    def cos(self) -> Tensor:
        """``cos(x)``."""
        a = self.data
        return Tensor._record(np.cos(a), (self,), lambda g: (-g * np.sin(a),))

    def log(self) -> Tensor:
        """``log(x)``."""
        a = self.data
        return Tensor._record(np.log(a), (self,), lambda g: (g / a,))

    def clamp(self, min=None, max=None) -> Tensor:  # noqa: A002 - torch's keyword names
        """Values limited to [min, max] (gradient 1 inside, 0 where clamped, as torch)."""
        a = self.data
        keep = np.ones(a.shape, bool)
        if min is not None:
            keep &= a >= min
        if max is not None:
            keep &= a <= max
        return Tensor._record(np.clip(a, min, max), (self,), lambda g: (g * keep,))

    clip = clamp

    def expand(self, *sizes) -> Tensor:
        """A broadcast view to ``sizes`` (-1 keeps a size); the gradient sums over the copies."""
        if len(sizes) == 1 and isinstance(sizes[0], (tuple, list)):
            sizes = tuple(sizes[0])
        lead = len(sizes) - self.data.ndim
        shape = tuple(self.data.shape[i - lead] if (s == -1 and i >= lead) else int(s)
                      for i, s in enumerate(sizes))
        old = self.data.shape
        return Tensor._record(np.broadcast_to(self.data, shape), (self,),
                              lambda g: (_unbroadcast(g, old),))

    def split(self, split_size_or_sections, dim: int = 0) -> tuple:
        """Pieces along ``dim`` of one size or of the given sizes (``torch.split``)."""
        n = self.data.shape[dim]
        if isinstance(split_size_or_sections, (int, np.integer)):
            bounds = list(range(0, n, int(split_size_or_sections))) + [n]
        else:
            bounds = [0] + np.cumsum(split_size_or_sections).tolist()
            if bounds[-1] != n:
                raise ValueError(f"split_size_or_sections: the sizes sum to {bounds[-1]}, the "
                                 f"dimension has {n}")
        lead = (slice(None),) * (dim % self.data.ndim)
        return tuple(self[lead + (slice(a, b),)] for a, b in zip(bounds[:-1], bounds[1:]))

    def __setitem__(self, index, value) -> None:
        if self.requires_grad and _MODE.enabled:
            raise TypeError("setitem: in-place assignment into a tensor that requires a "
                            "gradient is not recorded; build the tensor first, then make it a "
                            "Parameter")
        self.data[_data(index)] = _data(value)

    def permute(self, *dims) -> Tensor:
        """The axes reordered (``torch.permute``); the gradient is permuted back."""
        if len(dims) == 1 and isinstance(dims[0], (tuple, list)):
            dims = tuple(dims[0])
        dims = tuple(int(d) % self.data.ndim for d in dims)
        inv = tuple(np.argsort(dims))
        return Tensor._record(self.data.transpose(dims), (self,), lambda g: (g.transpose(inv),))

    def transpose(self, dim0: int, dim1: int) -> Tensor:
        """Two axes swapped (``torch.transpose``)."""
        return Tensor._record(np.swapaxes(self.data, dim0, dim1), (self,),
                              lambda g: (np.swapaxes(g, dim0, dim1),))

    def chunk(self, chunks: int, dim: int = 0) -> tuple:
        """At most ``chunks`` pieces along ``dim``, ``ceil(n / chunks)`` each (``torch.chunk``)."""
        n = self.data.shape[dim]
        return self.split(max(-(-n // int(chunks)), 1), dim)

    def flatten(self, start_dim: int = 0, end_dim: int = -1) -> Tensor:
        """Axes ``start_dim..end_dim`` merged into one."""
        shape = self.data.shape
        a, b = start_dim % max(len(shape), 1), end_dim % max(len(shape), 1)
        return self.reshape(shape[:a] + (-1,) + shape[b + 1:])

    def _cast(self, dtype) -> Tensor:
        if self.data.dtype == dtype:
            return self
        if self.requires_grad and _MODE.enabled:
            raise TypeError(f"{np.dtype(dtype).name}(): the tape records no gradient through a "
                            f"cast to a non-floating type; call .detach() first")
        return Tensor(self.data.astype(dtype))

    def float(self) -> Tensor:
        """A floating tensor (float64 here: see the module notes); itself if already floating."""
        if self.data.dtype.kind == "f":
            return self
        return Tensor(self.data.astype(np.float64))

    double = float

    def long(self) -> Tensor:
        """int64 values (``torch.long``)."""
        return self._cast(np.int64)

    def int(self) -> Tensor:
        """int32 values."""
        return self._cast(np.int32)

    def bool(self) -> Tensor:
        """Boolean values."""
        return self._cast(np.bool_)

    # ------------------------------------------------------------------ value-only operations
    def _constant_op(self, name: str):
        if self.requires_grad and _MODE.enabled:
            raise TypeError(f"{name}: the tape records no gradient for this operation; call it "
                            f"on tensor.detach(), or write the term as a (value, grad) function "
                            f"(see docs/custom_objective.md)")

    def _extreme(self, reduce: str, dim, keepdim: bool):
        """``max`` or ``min`` (``reduce``): the value, or ``(values, indices)`` along ``dim``."""
        self._constant_op(reduce)
        values = getattr(self.data, reduce)
        if dim is None:
            return Tensor(values())
        indices = getattr(self.data, "arg" + reduce)
        return MaxMin(Tensor(values(axis=dim, keepdims=keepdim)),
                      Tensor(indices(axis=dim, keepdims=keepdim)))

    def max(self, dim=None, keepdim: bool = False):
        """The maximum, or ``(values, indices)`` along ``dim`` (torch's convention); no gradient."""
        return self._extreme("max", dim, keepdim)

    def min(self, dim=None, keepdim: bool = False):
        """The minimum, or ``(values, indices)`` along ``dim``; no gradient."""
        return self._extreme("min", dim, keepdim)

    # the comparisons: the ufunc on the values, a constant tensor (no gradient)
    __lt__ = _comparison(np.less)
    __le__ = _comparison(np.less_equal)
    __gt__ = _comparison(np.greater)
    __ge__ = _comparison(np.greater_equal)
    __eq__ = _comparison(np.equal)
    __ne__ = _comparison(np.not_equal)

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        tracked = _tracks(*inputs)
        if tracked and method == "__call__" and ufunc in _RECORDED_UFUNCS and not kwargs:
            first = inputs[0]
            name = _RECORDED_UFUNCS[ufunc]
            if isinstance(first, Tensor):
                return getattr(first, name)(*inputs[1:])
            # a constant on the left: c + t, c - t, c * t, c / t
            reflected = {"__add__": "__radd__", "__sub__": "__rsub__", "__mul__": "__rmul__",
                         "__truediv__": "__rtruediv__"}.get(name)
            if reflected is not None:
                return getattr(inputs[1], reflected)(first)
        if tracked:
            raise TypeError(f"numpy.{ufunc.__name__}: the tape does not record this operation on "
                            f"a tensor that requires a gradient; use the tensor's own +, -, *, /, "
                            f"**, abs(), sum(), mean(), or call .detach() first")
        out = getattr(ufunc, method)(*(_data(x) for x in inputs), **kwargs)
        if isinstance(out, tuple):
            return tuple(Tensor(o) for o in out)
        return Tensor(out) if isinstance(out, np.ndarray) or np.isscalar(out) else out


class Parameter(Tensor):
    """A leaf tensor that requires a gradient (``torch.nn.Parameter``).

    Parameters
    ----------
    data : array_like
        Initial value (float; stored as float64).
    requires_grad : bool
        Default True.
    """

    __slots__ = ()

    def __init__(self, data, requires_grad: bool = True):
        super().__init__(np.array(_data(data), dtype=np.float64), requires_grad)

    def __repr__(self) -> str:
        return "Parameter containing:\n" + super().__repr__()


def tensor(data, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """A new tensor holding a copy of ``data`` (``torch.tensor``; ``device`` is ignored)."""
    arr = np.array(_data(data), dtype=dtype)
    if arr.dtype.kind in "iub" and requires_grad:
        arr = arr.astype(np.float64)
    return Tensor(arr, requires_grad)


def as_tensor(data, dtype=None, device=None) -> Tensor:
    """``data`` as a tensor, without copying a tensor (``torch.as_tensor``)."""
    if isinstance(data, Tensor) and dtype is None:
        return data
    return Tensor(np.asarray(_data(data), dtype=dtype))


def _size(size) -> tuple:
    if len(size) == 1 and isinstance(size[0], (tuple, list)):
        return tuple(size[0])
    return tuple(int(s) for s in size)


def full(size, fill_value, *, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """A tensor of ``size`` filled with ``fill_value`` (``torch.full``)."""
    shape = tuple(int(s) for s in size) if isinstance(size, (tuple, list)) else int(size)
    return Tensor(np.full(shape, fill_value, dtype=dtype or np.float64), requires_grad)


def zeros(*size, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """Zeros (``torch.zeros``)."""
    return Tensor(np.zeros(_size(size), dtype=dtype or np.float64), requires_grad)


def ones(*size, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """Ones (``torch.ones``)."""
    return Tensor(np.ones(_size(size), dtype=dtype or np.float64), requires_grad)


def zeros_like(x, *, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """Zeros shaped like ``x`` (``torch.zeros_like``)."""
    return Tensor(np.zeros_like(_data(x), dtype=dtype), requires_grad)


def ones_like(x, *, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """Ones shaped like ``x`` (``torch.ones_like``)."""
    return Tensor(np.ones_like(_data(x), dtype=dtype), requires_grad)


def arange(start, end=None, step=1, *, dtype=None, device=None) -> Tensor:
    """``torch.arange`` (integers unless a bound is a float)."""
    return Tensor(np.arange(start, end, step, dtype=dtype) if end is not None
                  else np.arange(start, dtype=dtype))


def linspace(start, end, steps: int, *, dtype=None, device=None) -> Tensor:
    """``steps`` evenly spaced values from ``start`` to ``end`` (``torch.linspace``)."""
    return Tensor(np.linspace(start, end, steps, dtype=dtype or np.float64))


def cat(tensors: Sequence, dim: int = 0) -> Tensor:
    """Concatenate along ``dim``; the gradient is split back (``torch.cat``)."""
    parts = [t if isinstance(t, Tensor) else Tensor(t) for t in tensors]
    sizes = np.cumsum([p.data.shape[dim] for p in parts])[:-1]
    value = np.concatenate([p.data for p in parts], axis=dim)
    return Tensor._record(value, parts, lambda g: tuple(np.split(g, sizes, axis=dim)))


def stack(tensors: Sequence, dim: int = 0) -> Tensor:
    """Stack along a new axis ``dim`` (``torch.stack``)."""
    return cat([(t if isinstance(t, Tensor) else Tensor(t)).unsqueeze(dim) for t in tensors], dim)


_RNG = np.random.default_rng()


def manual_seed(seed: int) -> None:
    """Seed the generator that :func:`geofit.pytorch3d.ops.sample_points_from_meshes` and the
    other random calls of geofit.pytorch3d draw from (``torch.manual_seed``)."""
    global _RNG
    _RNG = np.random.default_rng(seed)


def default_rng() -> np.random.Generator:
    """The generator seeded by :func:`manual_seed`."""
    return _RNG


def record(value, inputs: Sequence, vjp: Callable) -> Tensor:
    """Put your own differentiable operation on the tape.

    Parameters
    ----------
    value : array_like
        The operation's output, computed from the inputs' ``.data``.
    inputs : sequence of Tensor
        The tensors it was computed from.
    vjp : callable
        ``vjp(g) -> tuple`` of one gradient per input (None for no gradient): given
        ``g = dL/d value`` (shaped like ``value``), return ``dL/d input`` for each input.

    Returns
    -------
    Tensor
        Records ``vjp`` when an input requires a gradient (and gradients are enabled).

    Examples
    --------
    >>> import numpy as np
    >>> x = Parameter(np.array([0.0, 1.0]))
    >>> s = 1.0 / (1.0 + np.exp(-x.data))                      # a sigmoid ...
    >>> y = record(s, [x], lambda g: (g * s * (1.0 - s),))     # ... and its vjp
    >>> y.sum().backward()
    >>> np.round(x.grad.numpy(), 4)
    array([0.25  , 0.1966])
    """
    inputs = [t if isinstance(t, Tensor) else Tensor(t) for t in inputs]
    return Tensor._record(np.asarray(value), inputs, vjp)


def sigmoid(x) -> Tensor:
    """``torch.sigmoid``."""
    return (x if isinstance(x, Tensor) else Tensor(x)).sigmoid()


def randperm(n: int, *, device=None) -> Tensor:
    """A random permutation of ``range(n)`` from the :func:`manual_seed` generator."""
    return Tensor(_RNG.permutation(int(n)))


def randint(low: int = 0, high: int | None = None, size=(1,), *, device=None) -> Tensor:
    """Random integers in ``[low, high)`` from the :func:`manual_seed` generator."""
    if high is None:
        low, high = 0, low
    return Tensor(_RNG.integers(low, high, size=size))


def rand(*size, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """Uniform [0, 1) values from the :func:`manual_seed` generator (``torch.rand``)."""
    return Tensor(_RNG.random(_size(size)).astype(dtype or np.float64), requires_grad)


def randn(*size, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """Standard normal values from the :func:`manual_seed` generator (``torch.randn``)."""
    return Tensor(_RNG.standard_normal(_size(size)).astype(dtype or np.float64), requires_grad)


def full_like(x, fill_value, *, dtype=None, device=None, requires_grad: bool = False) -> Tensor:
    """``fill_value`` shaped like ``x`` (``torch.full_like``)."""
    return Tensor(np.full_like(_data(x), fill_value, dtype=dtype), requires_grad)


def eye(n: int, m: int | None = None, *, dtype=None, device=None) -> Tensor:
    """The identity matrix (``torch.eye``)."""
    return Tensor(np.eye(n, m, dtype=dtype or np.float64))


def from_numpy(array: np.ndarray) -> Tensor:
    """A tensor sharing ``array``'s memory when it is float64 (``torch.from_numpy``)."""
    return Tensor(array)


def is_tensor(obj) -> bool:
    """``isinstance(obj, Tensor)``."""
    return isinstance(obj, Tensor)


def chunk(input, chunks: int, dim: int = 0) -> tuple:  # noqa: A002 - torch's keyword name
    """``input.chunk(chunks, dim)``."""
    return as_tensor(input).chunk(chunks, dim)


def split(tensor, split_size_or_sections, dim: int = 0) -> tuple:
    """``tensor.split(split_size_or_sections, dim)``."""
    return as_tensor(tensor).split(split_size_or_sections, dim)


class device:  # noqa: N801 - torch's name
    """A device name (``torch.device``): everything runs on the CPU, so ``.to(device)`` and
    ``device=`` arguments accept any device and change nothing.

    Examples
    --------
    >>> device("cpu"), device("cuda:0").type
    (device(type='cpu'), 'cuda')
    """

    def __init__(self, type: str, index: int | None = None):  # noqa: A002 - torch's name
        name = str(getattr(type, "type", type))
        if ":" in name:
            name, idx = name.split(":", 1)
            index = int(idx)
        self.type = name
        self.index = index

    def __repr__(self) -> str:
        idx = "" if self.index is None else f", index={self.index}"
        return f"device(type={self.type!r}{idx})"

    def __str__(self) -> str:
        return self.type if self.index is None else f"{self.type}:{self.index}"

    def __eq__(self, other) -> bool:
        return str(self) == str(other)

    def __hash__(self) -> int:
        return hash(str(self))
