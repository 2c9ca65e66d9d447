"""``hybridfit plugins``: list the registered models, objectives and optimizers (a plugin whose
optional library is missing as unavailable, with the line that installs it; one that fails to
import as broken; an entry point that takes a built-in's name, or a name another distribution
registers too, as a conflict). It imports every plugin, to report on it; no other command does."""

from __future__ import annotations

from .. import registry
from ._common import declare_paths


def register(sub) -> None:
    p = sub.add_parser("plugins", help="list registered plugins with their distribution and doc")
    declare_paths(p)
    p.set_defaults(func=run)


def run(args) -> int:
    for kind, group in registry.GROUPS.items():
        print(f"{group}:")
        for info in registry.available(kind):
            if info.conflict:
                status = f"CONFLICT: {info.conflict}"
            elif info.error:
                status = f"FAILED TO IMPORT ({info.error})"
            elif info.unavailable:
                status = f"UNAVAILABLE: {info.unavailable}"
            else:
                status = info.doc
            print(f"  {info.name:<22} [{info.distribution}]  {status}")
    return 0
