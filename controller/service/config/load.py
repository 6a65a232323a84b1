"""Reading a robot file: `load_config` (a path, or None for the built-in robot)."""

from __future__ import annotations

import os
import tomllib

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
    return parse_config(data, source)
