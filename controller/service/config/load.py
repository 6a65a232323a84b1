"""Reading a robot file: `load_config` (a path, or None for the built-in robot), and the
robot description a daemon serves (`robot_description`)."""

from __future__ import annotations

import hashlib
import os
import tomllib
from typing import Any

from controller.service.config.parse import parse_config
from controller.service.config.robot import default_config
from controller.service.config.schema import ConfigError, RobotConfig
from controller.service.textfile import NotUtf8Error, decode_utf8


def load_config(path: str | os.PathLike[str] | None) -> RobotConfig:
    """Read and validate the TOML file at `path`; `None` returns `default_config()`.

    Raises ConfigError (naming the file) if the file cannot be read, is not valid TOML, or
    fails validation.
    """
    if path is None:
        return default_config()
    source = os.fspath(path)
    try:
        with open(source, "rb") as fh:
            raw = fh.read()
    except OSError as exc:
        raise ConfigError(source, "", f"cannot read: {exc.strerror or exc}") from exc
    try:
        text = decode_utf8(raw)
    except NotUtf8Error as exc:
        raise ConfigError(source, "", f"{exc} (TOML files must be UTF-8)") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML: {exc}") from exc
    return parse_config(data, source, text)


def robot_digest(text: str) -> str:
    """The digest that names a robot description's text: "sha256:" and the hex SHA-256 of its
    UTF-8 bytes. Raises nothing."""
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def robot_description(cfg: RobotConfig) -> dict[str, Any]:
    """What a daemon answers on `<prefix>/robot` (docs/zenoh.md): the robot's name, where its
    file was loaded from (`source`), the TOML text as loaded (`toml`) and its digest. Raises
    nothing."""
    return {
        "name": cfg.name,
        "source": cfg.source,
        "digest": robot_digest(cfg.text),
        "toml": cfg.text,
    }
