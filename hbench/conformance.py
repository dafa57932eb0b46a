"""The public path of :mod:`hbench.bench.conformance` for plugins: every name of that module,
under this name too (a stable name for plugins, without a warning)."""

from typing import Any

from hbench.bench import conformance as _module


def __getattr__(name: str) -> Any:
    return getattr(_module, name)


def __dir__() -> list[str]:
    return dir(_module)


if __name__ == "__main__":  # ``python -m hbench.conformance NAME``
    import sys

    sys.exit(_module.main())
