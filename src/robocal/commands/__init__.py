"""One module per ``robocal`` command: ``add_arguments(parser)`` and ``run(args) -> int``."""

from __future__ import annotations

from typing import Any

import yaml

from robocal.errors import ConfigError


def not_a_setting(item: str) -> str:
    """The error text of a command-line word that stands where settings go but has no ``=``."""
    return (
        f"{item!r} is not a setting: settings are key=value (e.g. {item}=<value>); options start with -- (see --help)"
    )


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """``key=value`` pairs (values parsed as YAML: numbers, lists, booleans); dotted keys nest."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(not_a_setting(item))
        key, raw = item.split("=", 1)
        try:
            value = yaml.safe_load(raw) if raw != "" else None
        except yaml.YAMLError:
            value = raw
        node = out
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {item!r} conflicts with an earlier one")
        node[parts[-1]] = value
    return out


#: the --robot option's help, one text for every command
ROBOT_HELP = "robot name (conf/robot/<name>.yaml), a YAML path, or a URDF as file.urdf#BASE:TIP"
