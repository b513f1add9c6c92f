"""Input files at the package's foundation: the error every spec dialect and robot file raises,
and the TOML reader that names the file in its messages.

`SpecError` lives here, below every layer that reads a user's file (robot files in
`tkujax.robot`, specs in `tkujax.studies`), so that one `except SpecError` catches them all.
"""

from __future__ import annotations

import tomllib
from pathlib import Path


class SpecError(ValueError):
    """A spec problem; the message names the key and what is allowed."""


def read_toml(path: str | Path, what: str = "spec file") -> dict:
    """A TOML file as a dict; SpecError naming the file when it is missing, a folder, not
    UTF-8, unreadable or not valid TOML."""
    path = Path(path)
    if path.is_dir():
        raise SpecError(f"{what} {path} is a folder, not a file")
    if not path.is_file():
        raise SpecError(f"{what} not found: {path}")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as err:
        raise SpecError(f"{what} {path}: not UTF-8 text (byte {err.start}); TOML files are "
                        "UTF-8") from err
    except OSError as err:
        raise SpecError(f"{what} {path}: cannot be read: {err.strerror}") from err
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SpecError(f"{path}: not valid TOML: {err}") from err
