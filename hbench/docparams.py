"""numpydoc ``Parameters`` sections written once for parameters that many functions share.

A module keeps a table ``{name: (type, description)}`` of the parameters its functions share
(``dw``, ``p``, ``shift`` ...) and decorates each function with :func:`parameters`, giving the
descriptions of its own parameters; the section is appended to the docstring at import, in the
signature's order (as matplotlib fills its shared docstring parts). A parameter described
nowhere is an error at import, so the section always names every parameter.
"""

from __future__ import annotations

import inspect
import textwrap
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def parameters(shared: Mapping[str, tuple[str, str]], **own: tuple[str, str]) -> Callable[[F], F]:
    """Append a numpydoc ``Parameters`` section to the decorated function's docstring.

    Parameters
    ----------
    shared : mapping of str to (str, str)
        ``name -> (type, description)`` of the parameters the module's functions share.
    **own : (str, str)
        ``(type, description)`` of this function's own parameters (taking precedence).

    Returns
    -------
    callable
        The decorator; it returns the function itself with its docstring completed.
    """

    def decorate(func: F) -> F:
        lines = ["Parameters", "----------"]
        for p in inspect.signature(func).parameters.values():
            kind, text = own[p.name] if p.name in own else shared[p.name]
            star = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "")
            lines.append(f"{star}{p.name} : {kind}")
            lines += textwrap.wrap(text, 88, initial_indent="    ", subsequent_indent="    ")
        doc = inspect.cleandoc(func.__doc__ or "")
        marker = "\nReturns\n-------"
        head, sep, tail = doc.partition(marker)
        section = "\n".join(lines)
        func.__doc__ = f"{head.rstrip()}\n\n{section}\n" + (f"{sep}{tail}" if sep else "")
        return func

    return decorate
