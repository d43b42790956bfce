"""Named training recipes: YAML files of config fields, shipped in this package.

A recipe names an algorithm and the fields of its config (:mod:`dockingrl.agents.config`) that
differ from the defaults, which are the paper's Tables 3-5. ``paper-sac``, ``paper-td3`` and
``paper-ppo`` are the paper's, literally; ``sac``, ``td3`` and ``ppo`` are dockingrl's
recommended ones, the same for every scenario. ``dockingrl train --recipe NAME`` takes a name
listed by :func:`recipe_names` or the path of a YAML file of the same form::

    algo: sac                 # sac, td3 or ppo
    description: one line     # optional
    base: sac                 # optional: a recipe whose fields this one starts from (a
                              # name, or a file: beside this one, else from the working folder)
    first_stage: sac          # optional, for a fine-tune: the recipe of the run that
                              # ``--init-from RUN_DIR`` takes (inherited from ``base``)
    config:                   # fields of the algorithm's config
      num_envs: 16
      hidden: [256, 256]

Fields given on the command line (or as ``overrides``) take precedence over the recipe's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from dockingrl.agents.config import (
    CONFIGS,
    TrainConfig,
    check_types,
    config_class,
    unknown_options,
)

_KEYS = ("algo", "description", "base", "first_stage", "config")
#: how deep ``base`` recipes may nest (a deeper chain is taken for a cycle)
_MAX_BASES = 8


@dataclass(frozen=True)
class Recipe:
    """A named set of config fields for one algorithm."""

    name: str
    algo: str
    description: str = ""
    config: dict[str, Any] = field(default_factory=dict)
    #: for a fine-tune, the recipe whose run ``--init-from`` takes ("" for a recipe that
    #: trains from scratch)
    first_stage: str = ""

    def make_config(self, **overrides) -> TrainConfig:
        """The recipe's config with ``overrides`` on top, validated; its ``recipe`` field
        records the recipe's name."""
        cls = config_class(self.algo)
        unknown = unknown_options(self.algo, overrides)
        if unknown:
            raise ValueError(f"unknown {self.algo} option(s): {', '.join(unknown)}")
        values = {**self.config, **overrides}
        if "hidden" in values:
            values["hidden"] = tuple(values["hidden"])
        cfg = cls(**values, recipe=self.name)
        cfg.validate()
        return cfg


def recipe_names() -> list[str]:
    """The recipes shipped with dockingrl, sorted."""
    root = resources.files(__package__)
    return sorted(p.name[: -len(".yaml")] for p in root.iterdir() if p.name.endswith(".yaml"))


def _beside(spec: str, other: str) -> str:
    """The recipe ``other`` that the recipe ``spec`` names: a file beside a recipe file is
    found first, then a shipped name, then a path from the working folder."""
    beside = Path(spec).parent / other
    if spec not in recipe_names() and other not in recipe_names() and beside.is_file():
        return str(beside)
    return other


def load_recipe(spec: str | Path, _depth: int = 0, *, check: bool = True) -> Recipe:
    """The shipped recipe named ``spec``, or the recipe in the YAML file at path ``spec``.
    With ``check`` its config is built and validated (a caller that builds the config with
    overrides at once and validates that, :meth:`Recipe.make_config`, passes ``False``).

    Raises ``ValueError`` (one line) for an unknown name, an unreadable or malformed file, an
    unknown algorithm or config field, a value of the wrong type, a ``base`` of another
    algorithm or in a cycle, or a ``first_stage`` that is unknown or of another algorithm."""
    import yaml

    if _depth > _MAX_BASES:
        raise ValueError(f"recipe {spec}: its bases nest deeper than {_MAX_BASES} (a cycle?)")
    spec = str(spec)
    if spec in recipe_names():
        name, text = spec, resources.files(__package__).joinpath(f"{spec}.yaml").read_text()
    else:
        path = Path(spec)
        if not path.is_file():
            raise ValueError(
                f"unknown recipe {spec!r}: neither a recipe name ({', '.join(recipe_names())}) "
                "nor a YAML file"
            )
        name = path.stem
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"recipe {spec}: cannot read it ({exc})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"recipe {spec}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"recipe {spec}: expected a mapping with keys {', '.join(_KEYS)}")
    extra = sorted(set(data) - set(_KEYS))
    if extra:
        raise ValueError(f"recipe {spec}: unknown key(s) {', '.join(map(str, extra))}")
    base = None
    if data.get("base") is not None:
        base = _load_part(spec, "base", _beside(spec, str(data["base"])), _depth)
        if data.get("algo", base.algo) != base.algo:
            raise ValueError(
                f"recipe {spec}: algo {data['algo']!r} differs from its base's ({base.algo!r})"
            )
        data.setdefault("algo", base.algo)
    algo = data.get("algo")
    if not isinstance(algo, str) or algo not in CONFIGS:
        raise ValueError(f"recipe {spec}: algo must be one of {', '.join(CONFIGS)} (got {algo!r})")
    config = data.get("config") or {}
    if not isinstance(config, dict):
        raise ValueError(f"recipe {spec}: config must be a mapping of fields")
    config = {**(base.config if base else {}), **config}
    first_stage = base.first_stage if base else ""
    if data.get("first_stage") is not None:
        first_stage = _beside(spec, str(data["first_stage"]))
    if first_stage:
        stage = _load_part(spec, "first_stage", first_stage, _depth)
        if stage.algo != algo:
            raise ValueError(
                f"recipe {spec}: first_stage {first_stage!r} is a {stage.algo} recipe, not {algo}"
            )
    recipe = Recipe(name, algo, str(data.get("description") or ""), config, first_stage)
    try:
        check_types(algo, config)
        if check:
            recipe.make_config()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"recipe {spec}: {exc}") from None
    return recipe


def _load_part(spec: str, key: str, part: str, depth: int) -> Recipe:
    """The recipe that ``spec``'s ``key`` (``base`` or ``first_stage``) names; an unknown one is
    refused naming ``spec`` and ``key``, so that the error points at the file to fix."""
    try:
        return load_recipe(part, depth + 1)
    except ValueError as exc:
        if str(exc).startswith("unknown recipe"):
            raise ValueError(f"recipe {spec}: its {key}: {exc}") from None
        raise


__all__ = ["Recipe", "load_recipe", "recipe_names"]
