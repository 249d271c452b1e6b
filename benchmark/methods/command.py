"""Methods that live in their own environment: a command line declared in a TOML file.

A method whose code needs its own dependencies (another CUDA build, another torch, the public
code of a paper) is run as a program, never imported::

    name = "my-method"                       # the run's method name (runs/<name>/...)
    description = "what it does"             # optional
    command = ["venv/bin/python", "predict.py", "--scene", "{scene}", "--out", "{output}"]
    workdir = "."                            # optional; relative to this file's folder (default)
    timeout = 1800                           # optional; seconds per sequence (default 3600)
    version = "1"                            # optional; change it to rerun cached sequences
    [env]                                    # optional; added to the environment
    OMP_NUM_THREADS = "2"

``trase-bench run --method path/to/method.toml --dataset D`` runs it like any method
(``benchmark.methods.get_method`` reads a name ending in ``.toml`` as such a file). For each
sequence the toolkit writes the method's input folder (``benchmark.methods.command_io``), runs
the command with its placeholders filled (``PLACEHOLDERS``), reads one predicted mask per test
frame back from the output folder and scores them (``benchmark.pipeline.command``).
docs/command-methods.md describes the input and output layouts.
"""

from __future__ import annotations

import dataclasses
import hashlib
import re
import string
from pathlib import Path

from benchmark.methods import Method, MethodError
from lazyspecs.presets import Context, Resolved

TOML_KEYS = ("name", "description", "command", "workdir", "timeout", "version", "env")
DEFAULT_TIMEOUT_S = 3600.0
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
# what a command's arguments and environment values may name, as {name} ({{ and }}: braces)
PLACEHOLDERS = {
    "input": "the input folder the toolkit wrote for this sequence",
    "output": "the (empty) folder the command writes its masks into: <frame>.png per test frame",
    "scene": "{input}/scene: the sequence's folder in its publisher's layout, with masks/<stem>.pt",
    "cameras": "{input}/cameras.json: training and test views, cameras and frame names",
    "prompts": "{input}/prompts.json: the benchmark's clicks per test frame and object",
    "dataset": "the benchmark's key (hypernerf, nerfds, neu3d, immersive, technicolor)",
    "sequence": "the sequence's name",
    "preset": "the run's preset (cpu, paper, ...)",
    "method_dir": "the folder of the method's TOML file",
}


class CommandError(MethodError):
    """A command method that cannot be read or did not produce its masks; one line naming the
    file (the TOML, or the command's log)."""


@dataclasses.dataclass
class CommandSettings:
    """A command method's settings, as its TOML declares them (``--set method.timeout=S``
    changes one for a run); recorded in results.json and hashed into the run's name."""

    preset: str = "cpu"  # the run's preset (a command reads it as {preset})
    name: str = ""
    description: str = ""
    version: str = ""
    command: list = dataclasses.field(default_factory=list)  # [program, arg, ...] with placeholders
    workdir: str = "."  # relative to the TOML's folder
    timeout: float = DEFAULT_TIMEOUT_S  # seconds per sequence
    env: dict = dataclasses.field(default_factory=dict)  # name -> value (placeholders allowed)
    toml_sha256: str = ""  # the TOML file's content: a changed file is another method version


def _fail(path: Path, problem: str) -> CommandError:
    return CommandError(f"{path}: {problem}")


def _placeholders_ok(path: Path, where: str, text: str) -> None:
    """Every {field} of ``text`` is a known placeholder (no conversions, no format specs)."""
    try:
        fields = [(f, conv, spec) for _, f, spec, conv in string.Formatter().parse(text) if f is not None]
    except ValueError as exc:  # a single { or }
        raise _fail(path, f"{where}: {exc} in {text!r} (write {{{{ and }}}} for literal braces)") from None
    for field, conv, spec in fields:
        if field not in PLACEHOLDERS or conv or spec:
            raise _fail(path, f"{where}: unknown placeholder {{{field}}} in {text!r} "
                              f"(known: {', '.join('{' + p + '}' for p in PLACEHOLDERS)})")


def read_command_toml(path: str | Path) -> CommandSettings:
    """The settings a method's TOML file declares, checked; a one-line error naming the file."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    path = Path(path)
    if not path.is_file():
        raise _fail(path, "command method file not found")
    raw = path.read_bytes()
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise _fail(path, f"not UTF-8 (byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise _fail(path, f"malformed TOML ({exc})") from None
    unknown = sorted(set(doc) - set(TOML_KEYS))
    if unknown:
        raise _fail(path, f"unknown key {unknown[0]!r} (known: {', '.join(TOML_KEYS)})")

    name = doc.get("name")
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise _fail(path, "name must be a string of letters, digits and . _ - (at most 64, not starting with a "
                          f"symbol), got {name!r}")
    from benchmark.methods import METHODS

    if name in METHODS:
        raise _fail(path, f"name {name!r} is a registered method; choose another name")
    command = doc.get("command")
    if not isinstance(command, list) or not command or not all(isinstance(a, str) and a for a in command):
        raise _fail(path, "command must be a non-empty list of non-empty strings (the program, then its "
                          f"arguments), got {command!r}")
    for i, arg in enumerate(command):
        _placeholders_ok(path, f"command[{i}]", arg)
    timeout = doc.get("timeout", DEFAULT_TIMEOUT_S)
    if isinstance(timeout, bool) or not isinstance(timeout, int | float) or not timeout > 0 \
            or timeout == float("inf"):
        raise _fail(path, f"timeout must be a number of seconds > 0, got {timeout!r}")
    for key in ("description", "version", "workdir"):
        if key in doc and not isinstance(doc[key], str):
            raise _fail(path, f"{key} must be a string, got {doc[key]!r}")
    env = doc.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(v, str) for v in env.values()):
        raise _fail(path, "[env] must be a table of strings (NAME = \"value\")")
    for k, v in env.items():
        _placeholders_ok(path, f"env.{k}", v)
    settings = CommandSettings(name=name, description=doc.get("description", ""), version=doc.get("version", ""),
                               command=list(command), workdir=doc.get("workdir", "."), timeout=float(timeout),
                               env=dict(env), toml_sha256=hashlib.sha256(raw).hexdigest())
    workdir_of(path, settings)  # an error now, not after the input is written
    return settings


def workdir_of(path: Path, settings: CommandSettings) -> Path:
    """The command's working folder: ``workdir`` relative to the TOML's folder, which must exist."""
    d = (Path(path).resolve().parent / settings.workdir).resolve()
    if not d.is_dir():
        raise _fail(path, f"workdir {settings.workdir!r} is not a folder ({d})")
    return d


def fill(text: str, values: dict[str, str]) -> str:
    """``text`` with its {placeholders} replaced (``values`` names every one of PLACEHOLDERS)."""
    return text.format_map(values)


def uses_placeholder(settings: CommandSettings, name: str) -> bool:
    texts = [*settings.command, *settings.env.values()]
    return any(f == name for t in texts for _, f, _, _ in string.Formatter().parse(t) if f is not None)


class CommandMethod(Method):
    """A method defined by a command line in a TOML file (module docstring). Its stages are
    the benchmark's masks and prompts, then its own (``stage_plan``): no reconstruction,
    no features here; the command does what it does in its own environment."""

    FEATURE_FIELDS = ()

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.declared = read_command_toml(self.path)
        self.name = self.declared.name

    def settings_class(self) -> type:
        return CommandSettings

    def resolve_settings(self, preset: str, ctx: Context) -> Resolved:
        """The TOML's settings under any run preset (the command reads it as {preset})."""
        if ctx.dataset is None:
            raise CommandError(f"{self.path}: a command method segments a benchmark's test views "
                               "(trase-bench run); a capture of one's own is fitted by a built-in method")
        config = dataclasses.replace(self.declared, preset=preset, command=list(self.declared.command),
                                     env=dict(self.declared.env))
        where = str(self.path)
        sources = {f.name: where for f in dataclasses.fields(CommandSettings)} | {"preset": "the run's preset"}
        return Resolved(preset, preset, config, sources)

    def check_settings(self, settings: CommandSettings) -> None:
        from benchmark.config import ConfigError

        if isinstance(settings.timeout, bool) or not settings.timeout > 0:
            raise ConfigError(f"--set method.timeout={settings.timeout!r}: a number of seconds > 0")
        if not settings.command or not all(isinstance(a, str) and a for a in settings.command):
            raise ConfigError(f"method.command={settings.command!r}: a non-empty list of strings")

    # the stages of its runs (benchmark.runner.STAGE_PLANS): the benchmark's masks and prompts,
    # the method's input folder, the command, the scores
    stage_plan = "command"

    def learn(self, *args, **kwargs):
        raise CommandError(f"{self.path}: a command method runs only through `trase-bench run` "
                           "(it segments the benchmark's test views in its own environment)")

    group = fit = segment = learn


def load_command_method(path: str | Path, **kwargs) -> CommandMethod:
    """The method of a TOML file (``get_method("path/to/method.toml")``)."""
    if kwargs:
        raise CommandError(f"{path}: a command method takes no options ({', '.join(kwargs)})")
    return CommandMethod(path)


__all__ = ["PLACEHOLDERS", "CommandError", "CommandMethod", "CommandSettings", "fill", "load_command_method",
           "read_command_toml", "uses_placeholder", "workdir_of"]
