"""``import geofit.pytorch3d.torch as torch``: the torch names PyTorch3D's six tutorials use.

With ``torch`` -> ``geofit.pytorch3d.torch`` and ``pytorch3d`` -> ``geofit.pytorch3d`` as the
only changes, the tutorials' code runs on numpy. This is not a general torch: it is
:mod:`geofit.pytorch3d.tensor` (a numpy array with a tape of hand-written vector-Jacobian
products, no general autodiff), :mod:`geofit.pytorch3d.nn` and :mod:`geofit.pytorch3d.optim`
under torch's names. Exactly these are provided:

* tensors: ``Tensor`` (also the constructor ``torch.Tensor(array)``), ``Size``, ``tensor``,
  ``as_tensor``, ``from_numpy``, ``is_tensor``, ``zeros``, ``ones``, ``full``, ``zeros_like``,
  ``ones_like``, ``full_like``, ``eye``, ``linspace``, ``arange``, ``cat``, ``stack``,
  ``chunk``, ``split``, ``sigmoid``;
* random: ``manual_seed``, ``rand``, ``randn``, ``randint``, ``randperm`` (one numpy
  generator, seeded by ``manual_seed``; the streams differ from torch's);
* dtypes: ``float32``, ``float``, ``float64``, ``double``, ``int32``, ``int64``, ``long``,
  ``bool``, ``uint8`` (numpy dtypes; floating values are always stored as float64);
* ``__version__`` (``"0+geofit"``, matching no torch release);
* gradients: ``no_grad``, ``is_grad_enabled``; ``Tensor.backward()`` runs the tape;
* devices: ``device``, ``cuda.is_available()`` (False), ``cuda.device_count()`` (0),
  ``cuda.set_device`` (raises: there is no CUDA); ``device=`` and ``.to(device)`` are accepted
  and ignored;
* ``optim``: ``SGD`` (momentum, dampening, Nesterov, weight decay) and ``Adam`` (PyTorch's
  update rules; ``param_groups[0]["lr"]`` may be changed between steps);
* ``nn``: ``Module`` (``parameters()``, ``named_parameters()``, ``register_buffer``, ``to``,
  ``train``/``eval``), ``Parameter``, ``Linear``, ``Sequential``, ``ReLU``, ``Softplus``,
  ``Sigmoid``, and ``nn.functional``: ``normalize`` (p = 2), ``grid_sample`` (bilinear, zero
  padding, on constant images), ``relu``, ``sigmoid``, ``softplus``.

The tensor methods (recorded on the tape when they carry a gradient): arithmetic ``+ - * /``
and ``**`` with a constant exponent (also reflected and in place as ``+=``), unary ``-``,
``abs``, ``sum``, ``mean``, ``sqrt``, ``exp``, ``log``, ``sin``, ``cos``, ``sigmoid``,
``clamp``/``clip``, indexing and slicing (ints, slices, ``None``, ``...``, index arrays and
tensors, ``range``), ``view``/``reshape``, ``flatten``, ``squeeze``, ``unsqueeze``,
``expand``, ``permute``, ``transpose``, ``split``, ``chunk``, ``unbind``, ``clone``; without a
gradient: ``max``/``min`` (with ``dim``: ``values, indices``), comparisons, ``detach``,
``cpu``, ``to``, ``numpy``, ``item``, ``tolist``, ``float``/``double``/``long``/``int``/``bool``,
``shape``/``size()``/``numel()``/``dim()``, iteration, ``len``, ``float()``/``int()``/``%``
formatting of one-element tensors, in-place assignment into tensors without a gradient. Any
other numpy function applied to a tensor that requires a gradient raises ``TypeError``.

PyTorch3D's own operations (losses, sampling, renderers) record geofit's analytic gradients on
the same tape: see :mod:`geofit.pytorch3d`.

Examples
--------
>>> import geofit.pytorch3d.torch as torch
>>> device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
>>> x = torch.full((3,), 0.5, device=device, requires_grad=True)
>>> optimizer = torch.optim.SGD([x], lr=0.1, momentum=0.9)
>>> loss = ((x - 1.0) ** 2).sum()
>>> loss.backward()
>>> optimizer.step()
>>> x.detach().numpy()
array([0.6, 0.6, 0.6])
"""
import numpy as _np

from .. import _common
from ..tensor import (
    Parameter,
    Size,
    Tensor,
    arange,
    as_tensor,
    cat,
    chunk,
    device,
    eye,
    from_numpy,
    full,
    full_like,
    is_grad_enabled,
    is_tensor,
    linspace,
    manual_seed,
    no_grad,
    ones,
    ones_like,
    rand,
    randint,
    randn,
    randperm,
    sigmoid,
    split,
    stack,
    tensor,
    zeros,
    zeros_like,
)
from . import cuda, nn, optim

#: Not a torch release: code that compares torch versions (the tutorials' install cells) sees
#: none it knows.
__version__ = "0+geofit"

float32 = float = _np.float32  # noqa: A001 - torch's names
float64 = double = _np.float64
int32 = _np.int32
int64 = long = _np.int64
bool = _np.bool_  # noqa: A001
uint8 = _np.uint8

__all__ = [
    "Parameter", "Size", "Tensor", "arange", "as_tensor", "bool", "cat", "chunk", "cuda",
    "device", "double", "eye", "float", "float32", "float64", "from_numpy", "full",
    "full_like", "int32", "int64", "is_grad_enabled", "is_tensor", "linspace", "long",
    "manual_seed", "nn", "no_grad", "ones", "ones_like", "optim", "rand", "randint", "randn",
    "randperm", "sigmoid", "split", "stack", "tensor", "uint8", "zeros", "zeros_like",
]

__getattr__ = _common.missing_names("geofit.pytorch3d.torch", {
    "save": "numpy.save / numpy.savez the arrays (tensor.detach().numpy())",
    "load": "numpy.load, then torch.tensor(array)",
    "compile": "not emulated: the tape runs numpy directly",
    "utils": "not emulated (no torch.utils.data): index the tensors directly",
    "bmm": "not recorded on the tape; write it with broadcasting * and .sum(dim)",
    "matmul": "not recorded on the tape; write it with broadcasting * and .sum(dim)",
    "einsum": "not recorded on the tape; write it with broadcasting * and .sum(dim)",
})
