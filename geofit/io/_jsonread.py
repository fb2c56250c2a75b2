"""Reading untrusted JSON (capture files, glTF): every failure a ValueError naming the file."""
from __future__ import annotations

import json

__all__ = ["parse_json"]


def parse_json(text, where: str):
    """``json.loads(text)`` with every failure a ValueError naming ``where``: malformed JSON,
    invalid UTF-8, an integer beyond Python's digit limit (4300 digits), nesting deeper than the
    recursion limit."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError(f"{where}: cannot read JSON: nested too deeply") from None
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError, the int digit limit
        raise ValueError(f"{where}: cannot read JSON: {str(exc)[:200]}") from None
