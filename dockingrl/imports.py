"""A package's public names imported on first use (PEP 562), so that importing the package
loads none of its heavy modules (torch, TorchRL) until a name is asked for."""

from __future__ import annotations

from importlib import import_module


def lazy_attributes(package: str, exports: dict[str, str]):
    """``(__getattr__, __dir__)`` for ``package``: each name of ``exports`` imported from its
    module on first use, so that importing the package imports none of them."""
    names = vars(import_module(package))

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module), name)
        names[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*names, *exports})

    return __getattr__, __dir__
