"""The live view's flags, shared by `uav-robots run` and `uav-robots replay`."""
from __future__ import annotations


def add_view_arguments(p) -> None:
    p.add_argument("--view", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                   help="serve a live view of the mission at http://127.0.0.1:PORT/ (default port 8765; 0: any free)")
    p.add_argument("--view-hold", type=float, default=None, metavar="S",
                   help="keep the view up S seconds after the mission (default: until Ctrl-C on a terminal, "
                        "else 0)")
