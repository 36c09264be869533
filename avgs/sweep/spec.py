"""What a sweep is: :class:`SweepSpec` (a TOML file and/or the command line) and its runs.

A sweep trains every scene with every setting and every seed. A *setting* is a name and
the ``avgs train`` options it adds (``no-context = "--no-context"``); ``common`` options go
to every run; ``{scene}`` in any option is replaced by the scene's id (e.g. a shared
stage 1: ``--stage1 runs/stage1/{scene}.ckpt.stage1.pt``). Runs start in the folder the sweep
started in, so relative paths in options mean what they mean there (on a cluster, every
machine needs that folder at the same path). Each run has a folder that stays
the same across restarts, ``OUT/<scene>/<setting>/seed<k>/``, holding ``scene.ckpt`` and its
log and curves as ``avgs train`` writes them.

A TOML file holds the same fields as the flags (``threads_per_run`` or ``threads-per-run``)::

    data = "data/presets"            # DATA_ROOT (RWAVS layout); paths are relative to the current folder
    out = "runs/main"
    scenes = ["office_0", "house_0"] # default: every scene under data
    seeds = [0, 1, 2]
    common = "--iterations 2000 --init sfm --no-gaussians"
    eval_options = "--phase source --phase-iterations 8"   # how avgs eval scores the checkpoints
    threads_per_run = 1
    gpus_per_run = 0.0
    [settings]
    avgs = ""
    no-context = "--no-context"
"""

from __future__ import annotations

import dataclasses
import re
import shlex
import sys
import typing
from dataclasses import dataclass, field
from pathlib import Path

CHECKPOINT = "scene.ckpt"
"A run's checkpoint, in its run folder (its log and curves beside it, as ``avgs train`` names them)."

EVAL_SPLITS = ("val", "train", "heldout", "none")
"What scores the finished checkpoints: a split of the scene (heldout: the impulse-response task's held-out source positions), or none."
RESERVED = ("--out", "--resume", "--seed", "--stage1-only", "--threads")
"``avgs train`` options the sweep sets itself, refused in settings (``--seed`` comes from ``seeds``)."

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")
"A setting's name: it becomes a folder name."


@dataclass
class SweepSpec:
    """A grid of ``avgs train`` runs and the resources each takes."""

    data: str = ""
    """Data root in the RWAVS layout (with position.json) holding the scenes."""
    out: str = "runs/sweep"
    """Folder of the run folders OUT/<scene>/<setting>/seed<k>/ and of results.json."""
    scenes: list[str] = field(default_factory=list)
    """Scene ids under the data root (default: every scene there)."""
    settings: dict[str, str] = field(default_factory=lambda: {"default": ""})
    """Setting name -> the avgs train options it adds (one shell-quoted string)."""
    seeds: list[int] = field(default_factory=lambda: [0])
    """Seeds: each run gets --seed K."""
    common: str = ""
    """avgs train options every run gets (one shell-quoted string)."""
    eval_options: str = ""
    """avgs eval options of the scoring (e.g. the synthesis: --phase source --phase-iterations 8)."""
    threads_per_run: int = 1
    """CPU threads of each run (OMP_NUM_THREADS and --threads): Ray places runs so the cores are not oversubscribed."""
    gpus_per_run: float = 0.0
    """GPU share of each run (0.25: four runs share a GPU); above 0, runs get --device cuda unless their options name a device."""
    retries: int = 1
    """Further attempts of a failed run in the same sweep, each resuming from its last checkpoint."""
    eval_split: str = "val"
    """What scores every finished checkpoint at the end: val, train, heldout (impulse-response scenes: pairs of held-out sources) or none."""
    address: str = ""
    """Ray cluster to join (auto, HOST:PORT or ray://HOST:10001); empty: start a local Ray on this machine."""
    num_cpus: int = 0
    """CPUs of the local Ray (0: every core); not with an address."""

    def validate(self) -> SweepSpec:
        if not self.data:
            raise ValueError("no data root: give --data DATA_ROOT (or data = \"...\" in the TOML file)")
        if not self.settings:
            raise ValueError("no settings: give --setting NAME=OPTIONS at least once")
        for name in self.settings:
            if not NAME.match(name):
                raise ValueError(f"setting name {name!r}: expected letters, digits, '.', '_', '+' or '-' (it names a folder)")
        if not self.seeds:
            raise ValueError("no seeds: give --seeds K [K ...]")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds {self.seeds}: a seed is repeated")
        if any(s < 0 for s in self.seeds):
            raise ValueError(f"seeds {self.seeds}: expected integers >= 0")
        if len(set(self.scenes)) != len(self.scenes):
            raise ValueError(f"scenes {self.scenes}: a scene is repeated")
        if self.threads_per_run < 1:
            raise ValueError(f"threads per run must be >= 1, got {self.threads_per_run}")
        if not 0.0 <= self.gpus_per_run:
            raise ValueError(f"GPUs per run must be >= 0 (a share like 0.25, or whole GPUs), got {self.gpus_per_run}")
        if self.gpus_per_run > 1 and self.gpus_per_run != int(self.gpus_per_run):
            raise ValueError(f"GPUs per run above 1 must be whole, got {self.gpus_per_run}")
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {self.retries}")
        if self.eval_split not in EVAL_SPLITS:
            raise ValueError(f"eval split {self.eval_split!r}: expected {', '.join(EVAL_SPLITS)}")
        if self.num_cpus < 0:
            raise ValueError(f"num_cpus must be >= 0, got {self.num_cpus}")
        if self.num_cpus and self.address:
            raise ValueError("--num-cpus sizes the local Ray; a cluster joined with --address has its own CPUs")
        for text in (self.common, self.eval_options, *self.settings.values()):
            split_options(text)
        return self


def split_options(text: str) -> list[str]:
    """Shell-split one options string; a clear error for unbalanced quotes."""
    try:
        return shlex.split(text)
    except ValueError as exc:
        raise ValueError(f"options {text!r}: {exc}") from None


def _toml_load(path: Path) -> dict:
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None


def _expect(value, kind, where: str):
    """``value`` checked against ``kind`` (the field's type: str, int, float, list[int], list[str], dict[str, str])."""
    origin = getattr(kind, "__origin__", None)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind in (str, int, float):
        if not isinstance(value, kind) or isinstance(value, bool):
            raise ValueError(f"{where}: expected {kind.__name__}, got {type(value).__name__} {value!r}")
        return value
    if origin is list:
        (item,) = kind.__args__
        if not isinstance(value, list) or not all(isinstance(v, item) and not isinstance(v, bool) for v in value):
            raise ValueError(f"{where}: expected a list of {item.__name__}, got {value!r}")
        return list(value)
    if origin is dict:
        if not isinstance(value, dict):
            raise ValueError(f"{where}: expected a table of name = \"options\", got {value!r}")
        out = {}
        for name, options in value.items():
            if isinstance(options, list) and all(isinstance(o, str) for o in options):
                options = shlex.join(options)
            if not isinstance(options, str):
                raise ValueError(f"{where}.{name}: expected an options string (or a list of strings), got {options!r}")
            out[name] = options
        return out
    raise TypeError(kind)  # pragma: no cover - every field's type is listed above


FIELD_TYPES = typing.get_type_hints(SweepSpec)
"Each field's type, which a TOML value must have."


def from_toml(path: str | Path) -> dict:
    """The fields a TOML file sets (``{field: value}``), each checked; unknown keys are errors."""
    path = Path(path)
    raw = _toml_load(path)
    names = {f.name for f in dataclasses.fields(SweepSpec)}
    out = {}
    for key, value in raw.items():
        name = key.replace("-", "_")
        if name not in names:
            raise ValueError(f"{path}: unknown key {key!r}; expected one of {', '.join(sorted(names))}")
        out[name] = _expect(value, FIELD_TYPES[name], f"{path}: {key}")
    return out


def make_spec(toml: str | Path | None, overrides: dict) -> SweepSpec:
    """Defaults, then the TOML file's fields, then ``overrides`` (the flags given: None = not given); validated."""
    values = from_toml(toml) if toml else {}
    values.update({k: v for k, v in overrides.items() if v is not None})
    return SweepSpec(**values).validate()


@dataclass(frozen=True)
class Run:
    """One training run of the grid."""

    scene: str
    """Scene id (its folder name under the data root)."""
    setting: str
    seed: int
    scene_dir: Path
    """The scene's folder (absolute)."""
    folder: Path
    """The run folder OUT/<scene>/<setting>/seed<k> (absolute)."""
    options: tuple[str, ...]
    """What this run adds to ``avgs train SCENE --out CKPT``: common, setting, --seed K (and --device cuda)."""
    scoring: tuple[str, ...] = ()
    """What its scoring adds to ``avgs eval`` (the sweep's eval options)."""
    workdir: Path | None = None
    """The folder the sweep started in: its runs start there too, so relative paths in options mean the same."""

    @property
    def name(self) -> str:
        return f"{self.scene}/{self.setting}/seed{self.seed}"

    @property
    def checkpoint(self) -> Path:
        return self.folder / CHECKPOINT


def run_options(spec: SweepSpec, setting: str, scene: str, seed: int) -> tuple[str, ...]:
    """The options of one run, ``{scene}`` replaced; refuses the options the sweep sets itself."""
    options = [o.replace("{scene}", scene) for o in split_options(spec.common) + split_options(spec.settings[setting])]
    for option in options:
        flag = option.split("=", 1)[0]
        if flag in RESERVED:
            raise ValueError(f"setting {setting!r}: {flag} is set by the sweep itself (run folders, seeds, threads); "
                             "leave it out")
    if spec.gpus_per_run > 0 and not any(o.split("=", 1)[0] == "--device" for o in options):
        options += ["--device", "cuda"]
    return (*options, "--seed", str(seed))


def expand(spec: SweepSpec, scene_dirs: list[Path]) -> list[Run]:
    """Every run of the grid, scene-major then setting then seed; folders under ``spec.out`` (absolute)."""
    out = Path(spec.out).resolve()
    runs = []
    for scene_dir in scene_dirs:
        scene_dir = Path(scene_dir).resolve()
        for setting in spec.settings:
            for seed in spec.seeds:
                folder = out / scene_dir.name / setting / f"seed{seed}"
                runs.append(Run(scene_dir.name, setting, seed, scene_dir, folder,
                                run_options(spec, setting, scene_dir.name, seed), tuple(split_options(spec.eval_options)),
                                Path.cwd()))
    return runs
