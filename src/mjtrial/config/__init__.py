"""The experiment's config: read strictly, then checked before any work.

- `check`: the schema first, then what a schema cannot say (`check_config`, `load_config`,
  `preflight`, ...).
- `read`: reading a run's config strictly (YAML without duplicate keys or alias bombs, the
  command line's `--config` values, how they merge).
- `studies`: the config check of the studies (variants, sweeps) and of a condition's model
  edits.
- `budget`: what a config will cost, and the limits it must keep.

Every public name of `check` (which includes those of `read`) is importable from
`mjtrial.config` itself, as before it was a package. They are imported at first use, not with
the package: `mjtrial.config.read` alone (the CLI's) must not load MuJoCo, which `check` does.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "DEFAULT_CONFIG",
    "MAX_CONFIG_BYTES",
    "MAX_CONFIG_VALUES",
    "SCHEMA_PATH",
    "ConfigError",
    "check_config",
    "load_config",
    "merge_config",
    "parse_config_args",
    "parse_config_text",
    "pilot_states",
    "policy_path_problem",
    "preflight",
    "read_config_file",
    "rerun_command",
    "run_configuration",
]

_SUBMODULES = ("budget", "check", "read", "studies")


def __getattr__(name: str) -> Any:
    if name.startswith("__") or name in _SUBMODULES:
        raise AttributeError(f"module 'mjtrial.config' has no attribute {name!r}")
    # MuJoCo and the task machinery: only when a name of the check is asked for
    from mjtrial.config import check

    try:
        return getattr(check, name)
    except AttributeError:
        raise AttributeError(f"module 'mjtrial.config' has no attribute {name!r}") from None


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
