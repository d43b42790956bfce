"""How a config saved with a run (its ``config.json``) compares with a config asked for now:
the fields that make them different runs, with a field the saved config lacks (one added to
dockingrl after the run started) read as the config class's default."""

from __future__ import annotations

from typing import Any

#: fields a saved config may differ in from the one asked for without being another run:
#: where and how fast it runs and how it logs
HOW_NOT_WHAT = ("threads", "device", "out", "run_name", "logger", "wandb_online", "compile")


def as_saved(value: Any) -> Any:
    """``value`` as a ``config.json`` reads it back (a tuple as a list)."""
    return list(value) if isinstance(value, tuple) else value


def config_mismatch(saved: dict, wanted: dict, defaults: dict | None = None) -> list[str]:
    """The fields beyond :data:`HOW_NOT_WHAT` in which the saved config ``saved`` differs from
    ``wanted``. A field ``saved`` lacks counts as its value in ``defaults``, the config class's
    defaults (without them, as missing)."""
    old = {**{k: as_saved(v) for k, v in (defaults or {}).items()}, **saved}
    keys = (set(saved) | set(wanted)) - set(HOW_NOT_WHAT)
    new = {k: as_saved(v) for k, v in wanted.items()}
    return sorted(k for k in keys if old.get(k) != new.get(k))


def saved_differs(saved: dict, cfg) -> list[str]:
    """:func:`config_mismatch` of ``saved`` against the config object ``cfg``, a field
    ``saved`` lacks read as ``cfg``'s class default."""
    return config_mismatch(saved, cfg.to_dict(), type(cfg)().to_dict())
