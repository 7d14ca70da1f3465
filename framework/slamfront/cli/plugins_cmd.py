"""``slamfront plugins [--kind K] [--json]``"""

from __future__ import annotations

import argparse
import json
import sys

from slamfront.kinds import KINDS


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "plugins", help="list the installed plugins", description="List every plugin slamfront can load."
    )
    parser.add_argument("--kind", choices=KINDS, help="only plugins of this kind")
    parser.add_argument("--json", action="store_true", help="machine-readable, with each config's JSON schema")
    parser.add_argument("-p", "--plugin-module", action="append", default=[], metavar="MODULE",
                        help="also register this plugin module (importable name; repeatable)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.registry import PluginRegistry

    registry = PluginRegistry(modules=args.plugin_module)
    infos = registry.all(args.kind)
    for problem in registry.broken:  # an installed package's plugins are missing: an error here, at least
        print(f"slamfront: error: {problem}", file=sys.stderr)
    if args.json:
        for problem in registry.skipped:  # stdout stays one JSON document
            print(f"slamfront: warning: invalid plugin skipped: {problem}", file=sys.stderr)
        print(json.dumps(
            [
                {
                    "name": info.name,
                    "kind": info.kind,
                    "version": info.version,
                    "summary": info.cls.summary(),
                    "doc": (info.cls.__doc__ or "").strip(),
                    "module": info.module,
                    "distribution": info.distribution,
                    "origin": info.origin,
                    "config_schema": info.cls.Config.model_json_schema(),
                }
                for info in infos
            ],
            indent=2,
        ))
        return 2 if registry.broken else 0
    if registry.skipped:  # first, where the author of the plugin looks
        print("invalid plugins, skipped (fix these to use them):")
        for problem in registry.skipped:
            print(f"  {problem}")
    width = max((len(i.name) for i in infos), default=4)
    current = None
    for info in infos:
        if info.kind != current:
            current = info.kind
            print(f"\n{current}:")
        origin = "" if info.distribution == "slamfront" else f"  [{info.origin}]"
        print(f"  {info.name:<{width}}  {info.cls.summary()}{origin}")
        for field_name, field in info.cls.Config.model_fields.items():
            if field.is_required():
                shown = "(required)"
            else:
                shown = repr(field.default if field.default_factory is None else field.default_factory())
            print(f"  {'':<{width}}    {field_name} = {shown}  {field.description or ''}".rstrip())
    return 2 if registry.broken else 0
