"""Old names that keep working for one release: each use warns (``DeprecationWarning``) with the new address.

Every old name is listed in ``CHANGELOG.md`` under "Deprecated" and goes in the release after the next. Two kinds:

- a name that moved or was renamed: the old module gets ``__getattr__ = moved(__name__, {old: (new address,
  object)})``, which Python calls only for names the module does not define, so the old name warns and forwards;
- a keyword argument that was renamed: :func:`renamed_keyword` inside the function.
"""
from __future__ import annotations

import warnings
from typing import Any, Callable

__all__ = ["warn", "moved", "renamed_keyword"]


def warn(old: str, new: str, stacklevel: int = 3) -> None:
    """One DeprecationWarning: ``old`` is deprecated, use ``new``; attributed to the caller's caller."""
    warnings.warn(f"{old} is deprecated and will be removed in the next release; use {new}", DeprecationWarning,
                  stacklevel=stacklevel)


def moved(module: str, names: dict[str, tuple[str, Any]]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``module``: ``names[old] = (new address, object)``; an old name warns and returns
    the object, any other missing name raises AttributeError as usual."""
    def __getattr__(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        address, obj = names[name]
        warn(f"{module}.{name}", address)
        return obj
    return __getattr__


def renamed_keyword(function: str, old: str, new: str, old_value: Any, new_value: Any = None) -> Any:
    """The value a caller passed as keyword ``old`` of ``function``, now called ``new`` (warned); a TypeError if the
    caller passed both. Call it only when ``old_value`` was given (is not None)."""
    if new_value is not None:
        raise TypeError(f"{function}() got both {old}= (deprecated) and {new}=; pass {new}= only")
    warn(f"{function}({old}=...)", f"{function}({new}=...)", stacklevel=4)
    return old_value
