"""Reading a run's config strictly: YAML without duplicate keys or alias bombs, the command
line's `--config` values, and how `--configfile` files and they merge into a run's
configuration. What the values must be is `mjtrial.config`'s check.
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from mjtrial.files.layout import CONFIG_FILE
from mjtrial.files.schemas import FAST_LOADER

# A config is a few hundred lines; anything far larger is a mistake or an attack (a YAML
# "billion laughs" document expands a few lines of aliases into billions of values).
MAX_CONFIG_BYTES = 1 << 20
MAX_CONFIG_VALUES = 100_000


class ConfigError(ValueError):
    """The config does not describe a runnable experiment; the message is one line."""


def _duplicate_key(node: yaml.Node, path: tuple[str, ...] = ()) -> tuple[str, int] | None:
    """The first key that appears twice in one mapping, with its line; YAML loaders keep the
    last silently, so a duplicated condition would quietly replace the first."""
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key, value in node.value:
            name = str(key.value)
            if name in seen:
                return ".".join((*path, name)), key.start_mark.line + 1
            seen.add(name)
            found = _duplicate_key(value, (*path, name))
            if found:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            found = _duplicate_key(item, (*path[:-1], f"{path[-1]}[{i}]") if path else (f"[{i}]",))
            if found:
                return found
    return None


def _expanded_size(node: yaml.Node, sizes: dict[int, int]) -> int:
    """How many values `node` holds once its aliases are expanded, counted once per node
    (aliases share nodes, so this is linear in the document, not in its expansion)."""
    key = id(node)
    if key not in sizes:
        sizes[key] = 0  # a recursive alias counts as nothing more
        if isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        elif isinstance(node, yaml.SequenceNode):
            children = node.value
        else:
            children = []
        sizes[key] = 1 + sum(_expanded_size(c, sizes) for c in children)
    return sizes[key]


def parse_config_text(text: str, *, source: str) -> dict[str, Any]:
    """Parse YAML config text strictly: no duplicate keys, no alias bombs; no schema check."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ConfigError(f"{source}: not valid YAML{where}: {problem}") from None
    if node is not None and _expanded_size(node, {}) > MAX_CONFIG_VALUES:
        raise ConfigError(
            f"{source}: expands to more than {MAX_CONFIG_VALUES} values through YAML aliases; "
            "expected a plain config"
        )
    config = yaml.load(text, Loader=FAST_LOADER)  # valid YAML, its size checked above
    duplicate = _duplicate_key(node) if node is not None else None
    if duplicate:
        key, line = duplicate
        raise ConfigError(f"{source}: {key}: duplicate key (line {line}); expected each key once")
    if not isinstance(config, dict):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level")
    return config


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Read and parse a YAML config file strictly (see `parse_config_text`)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"{path}: {size} bytes; expected a config file of at most {MAX_CONFIG_BYTES}"
            )
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data[: err.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}: not UTF-8 text (byte 0x{data[err.start]:02x} on line {line}); "
            "expected a UTF-8 YAML file"
        ) from None
    return parse_config_text(text, source=str(path))


def parse_config_args(args: list[str] | None) -> dict[str, Any]:
    """The `--config key=value` arguments, each value read as YAML (skipped if it is not).

    Snakemake reads a nested value such as `states={n: 50}` with YAML's base loader, which
    leaves every scalar a string (`'50'`); reading it as YAML gives what the user typed.
    """
    parsed: dict[str, Any] = {}
    for arg in args or []:
        key, sep, value = arg.partition("=")
        if not sep:
            raise ConfigError(f"--config {arg}: expected key=value")
        try:
            node = yaml.compose(value, Loader=yaml.SafeLoader)
        except yaml.YAMLError:
            continue  # not YAML: Snakemake's own reading of it stands
        if node is not None and _expanded_size(node, {}) > MAX_CONFIG_VALUES:
            raise ConfigError(f"--config {key}: expands to more than {MAX_CONFIG_VALUES} values")
        parsed[key] = yaml.safe_load(value)
    return parsed


def merge_config(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `override`'s values on top, recursively (how Snakemake merges configs)."""
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = merge_config(merged[key], value)
        else:
            merged[key] = value
    return merged


def run_configuration(
    configfiles: list[str | Path],
    config_args: list[str] | None,
    given: Mapping[str, Any],
    *,
    default: str | Path = CONFIG_FILE,
    repo_root: Path | None = None,
) -> tuple[Path, dict[str, Any], dict[str, Any]]:
    """A run's configuration: its file, the values given on top of it, and the two merged.

    A `--configfile` that names an `experiment` is a whole experiment (say,
    config/cartpole_latency.yaml): it is the run's file, in place of config/config.yaml (the
    last one, if several do); merged on top of the default, two experiments' conditions and
    ranges would mix. Other `--configfile` files, then the `--config` values, go on top of it,
    as Snakemake merges them. `given` is Snakemake's config (its reading of `--config`).
    A `--configfile` outside `repo_root` (the folder Snakemake runs in) is refused: the run
    records its file relative to the repository and the crate, `source/` and the zip hold the
    repository's files only, so the zip would not verify elsewhere.
    """
    files = [Path(f) for f in configfiles]
    for f in files if repo_root is not None else ():
        root = Path(repo_root).resolve()
        if not (root / f).resolve().is_relative_to(root):
            raise ConfigError(
                f"--configfile {os.path.relpath(root / f, root)}: outside the repository; "
                "expected a config file inside it "
                "(say, config/), so that the run's source/, crate and zip hold it"
            )
    whole = [f for f in files if "experiment" in read_config_file(f)]
    base = whole[-1] if whole else Path(default)
    command_line: dict[str, Any] = {}
    for f in files:
        if f not in whole:
            command_line = merge_config(command_line, read_config_file(f))
    keys = [arg.partition("=")[0] for arg in config_args or []]
    command_line = merge_config(command_line, {k: given[k] for k in keys if k in given})
    command_line = merge_config(command_line, parse_config_args(config_args))
    return base, command_line, merge_config(read_config_file(base), command_line)


def rerun_command(configfiles: Sequence[str], config_args: Sequence[str]) -> str:
    """`snakemake -c2` with the run's `--configfile` and `--config` arguments, as given."""
    words = ["snakemake", "-c2"]
    words += [w for f in configfiles for w in ("--configfile", f)]
    words += ["--config", *config_args] if config_args else []
    return shlex.join(words)
