"""Grid files: the shipped ones (``dockingrl/grids/``) and YAML files of one's own, read and
validated into a :class:`Grid` of :class:`Trial` s."""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from dockingrl.scenarios import SCENARIOS

_GRID_KEYS = ("name", "out", "collect", "threads", "scenarios", "overrides", "groups")
_GROUP_KEYS = ("recipes", "scenarios", "seeds", "overrides", "estimate_s")


@dataclass(frozen=True)
class Trial:
    """One training run of a grid."""

    recipe: str
    scenario: str
    seed: int
    overrides: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    estimate_s: float = 0.0

    @property
    def name(self) -> str:
        return f"{self.recipe}__{self.scenario}__s{self.seed}"

    def config(self, out: Path, threads: int):
        """The trial's validated training config."""
        from dockingrl.recipes import load_recipe

        return load_recipe(self.recipe).make_config(
            scenario=self.scenario,
            seed=self.seed,
            threads=threads,
            out=str(out),
            run_name=self.name,
            **self.overrides,
        )


@dataclass
class Grid:
    """A grid file, resolved: where its runs go and its trials in the order they start."""

    name: str
    out: Path
    collect: Path | None
    threads: int
    trials: list[Trial]

    def run_dir(self, trial: Trial) -> Path:
        return self.out / trial.name


def select_trials(
    grid: Grid, patterns: list[str] | None = None, threads: int | None = None
) -> Grid:
    """``grid`` with only the trials whose names match one of the shell-style ``patterns``
    (``td3__*``, ``*__compound__s1``; in the grid's order) and, if given, ``threads`` torch
    threads per trial. A trial keeps its folder and config, so running part of a grid and then
    the whole one finds that part finished; the thread count is how a trial runs, not what it
    computes, so a trial may resume with another. Raises ``ValueError`` (one line) for a pattern
    that matches no trial or a thread count below 1."""
    from dataclasses import replace
    from fnmatch import fnmatchcase

    if threads is not None and threads < 1:
        raise ValueError(f"grid {grid.name}: threads must be >= 1 (got {threads})")
    trials = grid.trials
    if patterns:
        unmatched = [p for p in patterns if not any(fnmatchcase(t.name, p) for t in trials)]
        if unmatched:
            raise ValueError(
                f"grid {grid.name}: no trial matches {', '.join(map(repr, unmatched))} "
                f"(names are RECIPE__SCENARIO__sSEED, e.g. {trials[0].name})"
            )
        trials = [t for t in trials if any(fnmatchcase(t.name, p) for p in patterns)]
    return replace(grid, trials=trials, threads=threads or grid.threads)


def grid_names() -> list[str]:
    """The grid files shipped with dockingrl."""
    root = resources.files("dockingrl.grids")
    return sorted(p.name[: -len(".yaml")] for p in root.iterdir() if p.name.endswith(".yaml"))


def _mapping(value, where: str) -> dict:
    """``value`` if it is a mapping of field names (None: an empty one), else a ValueError."""
    if value is None:
        return {}
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ValueError(f"{where} must be a mapping of config fields (got {value!r})")
    return value


def _names(value, where: str) -> list:
    """``value`` if it is a list of names, else a ValueError (a bare string would be read
    letter by letter)."""
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{where} must be a list of names, e.g. [a, b] (got {value!r})")
    return value


def load_grid(spec: str | Path, out: str | Path | None = None, collect: str | None = None) -> Grid:
    """The shipped grid named ``spec`` or the grid file at path ``spec``::

        name: table6
        out: runs/table6              # run folders (relative to the working directory)
        collect: results/table6/trials  # optional: each finished trial's small files
        threads: 1                    # torch threads (and Ray CPUs) per trial
        scenarios: [no_noise, noise, filtered, compound]
        overrides: {eval_episodes: 100}  # config fields for every trial
        groups:
          - recipes: [sac]
            seeds: [0, 1, 2]
            overrides: {total_steps: 500000}
            estimate_s: 7000          # expected seconds of one trial on one core

    A relative ``init_from`` (a second stage that fine-tunes another run) is resolved from the
    working directory, as ``out`` is.
    Trials start seed by seed (every cell's seed 0 first), in the groups' order within a seed.
    ``out`` and ``collect`` override the file's. Every trial's config is built and validated
    here, so a bad grid fails before anything runs. Raises ``ValueError`` (one line)."""
    import yaml

    spec = str(spec)
    if spec in grid_names():
        text = resources.files("dockingrl.grids").joinpath(f"{spec}.yaml").read_text()
    elif Path(spec).is_file():
        try:
            text = Path(spec).read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"grid {spec}: not a readable text file ({exc})") from None
    else:
        raise ValueError(
            f"unknown grid {spec!r}: neither a grid name ({', '.join(grid_names())}) nor a file"
        )
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"grid {spec}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or not isinstance(data.get("groups"), list):
        raise ValueError(f"grid {spec}: expected a mapping with a list of groups")
    extra = sorted(set(data) - set(_GRID_KEYS))
    if extra:
        raise ValueError(f"grid {spec}: unknown key(s) {', '.join(map(str, extra))}")
    for key in ("name", "out", "collect"):
        if data.get(key) is not None and not isinstance(data[key], str):
            raise ValueError(f"grid {spec}: {key} must be a string (got {data[key]!r})")
    threads = data.get("threads", 1)
    if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
        raise ValueError(f"grid {spec}: threads must be an integer >= 1 (got {threads!r})")
    base = _mapping(data.get("overrides"), f"grid {spec}: overrides")
    trials: list[tuple[int, int, Trial]] = []
    for g, group in enumerate(data["groups"]):
        if not isinstance(group, dict) or set(group) - set(_GROUP_KEYS):
            raise ValueError(
                f"grid {spec}: group {g} must be a mapping of {', '.join(_GROUP_KEYS)}"
            )
        where = f"grid {spec}: group {g}"
        scenarios = _names(
            group.get("scenarios", data.get("scenarios", list(SCENARIOS))), f"{where}: scenarios"
        )
        for scenario in scenarios:
            if scenario not in SCENARIOS:
                raise ValueError(f"grid {spec}: unknown scenario {scenario!r}")
        seeds = group.get("seeds", [0])
        if (
            not isinstance(seeds, list)
            or not seeds
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
        ):
            raise ValueError(f"{where}: seeds must be a list of integers >= 0 (got {seeds!r})")
        estimate = group.get("estimate_s", 0.0)
        if (
            isinstance(estimate, bool)
            or not isinstance(estimate, (int, float))
            or not 0 <= estimate < float("inf")
        ):
            raise ValueError(f"{where}: estimate_s must be a finite number >= 0 (got {estimate!r})")
        overrides = {**base, **_mapping(group.get("overrides"), f"{where}: overrides")}
        if isinstance(overrides.get("init_from"), str) and overrides["init_from"]:
            # a run folder named from where the grid runs, wherever its trials' processes run
            overrides["init_from"] = str(Path(overrides["init_from"]).resolve())
        for recipe in _names(group.get("recipes") or [], f"{where}: recipes"):
            for seed in seeds:
                for scenario in scenarios:
                    trial = Trial(
                        str(recipe),
                        scenario,
                        seed,
                        dict(overrides),
                        float(estimate),
                    )
                    trials.append((seed, g, trial))
    names = [t.name for _, _, t in trials]
    if len(set(names)) != len(names):
        raise ValueError(f"grid {spec}: a trial appears twice")
    if not trials:
        raise ValueError(f"grid {spec}: no trials")
    grid = Grid(
        str(data.get("name") or Path(spec).stem),
        Path(out or data.get("out") or f"runs/{Path(spec).stem}"),
        Path(collect) if collect else (Path(data["collect"]) if data.get("collect") else None),
        threads,
        [t for _, _, t in sorted(trials, key=lambda x: (x[0], x[1]))],
    )
    for trial in grid.trials:
        try:
            trial.config(grid.out, threads)
        except ValueError as exc:
            raise ValueError(f"grid {spec}: trial {trial.name}: {exc}") from None
    return grid
