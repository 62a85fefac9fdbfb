"""A mapping's DBC (or ARXML, KCD, SYM) read and parsed with cantools, bounded and with one-line errors:
the agent's DBC source and the simulator's ``--profile dbc:MAPPING.toml`` load it the same way."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from protocol.console import library_message
from protocol.files import NotARegularFile, read_regular
from protocol.signal_mapping import MappingError, SignalMapping, UnreadableFile

#: The largest database read (see :func:`load_dbc`); a robot controller's DBC is a few kB.
MAX_DBC_BYTES = 2 << 20
_FORMATS = {".dbc": "dbc", ".arxml": "arxml", ".kcd": "kcd", ".sym": "sym"}


def load_dbc(mapping: SignalMapping) -> Any:
    """The mapping's database, read whole (a regular file of at most :data:`MAX_DBC_BYTES`: cantools
    needs ≈ 200 bytes of memory per byte of text) and parsed by cantools; MappingError otherwise
    (UnreadableFile for an I/O error)."""
    import cantools
    path = mapping.dbc
    where = mapping.where("dbc")
    try:
        raw = read_regular(path or Path(), MAX_DBC_BYTES)
    except FileNotFoundError:
        raise MappingError(f"{where}: file {path} not found") from None
    except NotARegularFile as exc:
        raise MappingError(f"{where}: {path}: {exc.reason} (a DBC of a robot controller is a few kB; keep the "
                           "messages the mapping names)") from None
    except OSError as exc:
        raise UnreadableFile(f"{where}: cannot read {path}: {exc.strerror or exc}") from None
    suffix = (path or Path()).suffix.lower()
    text = raw.decode("cp1252" if suffix == ".dbc" else "utf-8", errors="replace")   # cantools' own default
    try:
        return cantools.database.load_string(text, database_format=_FORMATS.get(suffix), strict=False)
    except Exception as exc:  # noqa: BLE001 — cantools raises its own ParseError, UnsupportedDatabaseFormatError …
        raise MappingError(f"{where}: cannot load {path}: {type(exc).__name__}: {library_message(exc)}") from None
