"""edge-monitor deploy: print a file an edge box needs to run the agent as a service, as shipped in this
package (a wheel user has no checkout): the systemd unit and its environment file, the logrotate snippet,
the CAN interface's systemd-networkd file or bring-up script, the default agent.toml, and the example
mappings with the DBC and EDS they name (mappings/X.toml refers to ../dbc/ and ../eds/: keep the three
folders side by side). The online documentation is docs/OPERATIONS.md and docs/CONNECTING.md of the
project's repository.

  edge-monitor deploy --list
  edge-monitor deploy edge-monitor.service > /etc/systemd/system/edge-monitor.service
  edge-monitor deploy agent.toml > /etc/edge-monitor/agent.toml
  mkdir -p mappings eds && edge-monitor deploy mappings/cia402.toml > mappings/cia402.toml \
      && edge-monitor deploy eds/cia402_drive.eds > eds/cia402_drive.eds
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from importlib.resources.abc import Traversable

from protocol.console import UsageError

#: name prefix → (package, folder in it) of the files this command prints.
_FOLDERS = {"": ("edge_monitor", "deploy"), "mappings/": ("protocol", "mappings"), "dbc/": ("protocol", "dbc"),
            "eds/": ("protocol", "eds")}


def shipped_files() -> dict[str, Traversable]:
    """The files by the name this command takes."""
    files: dict[str, Traversable] = {"agent.toml": resources.files("edge_monitor.defaults").joinpath("agent.toml")}
    for prefix, (package, folder) in _FOLDERS.items():
        for entry in resources.files(package).joinpath(folder).iterdir():
            if entry.is_file() and not entry.name.endswith((".py", ".pyc")):
                files[prefix + entry.name] = entry
    return dict(sorted(files.items()))


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("deploy", help="print the service files shipped with the agent (systemd unit, "
                                                  "logrotate, CAN bring-up, agent.toml, mappings)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", nargs="?", help="the file to print (see --list)")
    parser.add_argument("--list", action="store_true", help="list the files")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    files = shipped_files()
    if args.list or args.name is None:
        print("\n".join(files))
        return 0
    if args.name not in files:
        raise UsageError(f"{args.name!r} is not shipped; the files are: {', '.join(files)}")
    sys.stdout.write(files[args.name].read_text(encoding="utf-8"))
    return 0
