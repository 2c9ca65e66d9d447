"""``hybridfit plugins``: list the registered models, objectives and optimizers."""

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
            status = f"FAILED TO IMPORT ({info.error})" if info.error else info.doc
            print(f"  {info.name:<22} [{info.distribution}]  {status}")
    return 0
