"""``slamfront inspect LOG... [--json] [--recipe] [--validate]``"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.errors import LogError
from slamfront.text import printable, shorten

if TYPE_CHECKING:
    from slamfront.mcaplog.reader import LogSummary
    from slamfront.message_types import MessageTypes


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "inspect", help="summarise an MCAP log", description="Topics, schemas, message counts and time span of a log."
    )
    parser.add_argument("log", type=Path, nargs="+",
                        help="an .mcap file (or a run folder holding run.mcap); several are inspected in turn")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--recipe", action="store_true", help="print the recipe the log embeds (YAML) and nothing else")
    parser.add_argument(
        "--validate", action="store_true",
        help="also decode every message with the installed message types (slamfront's and its plugins'), check "
        "those of types no installed package declares against the schema the log embeds, and note what the "
        "embedded recipe would do on replay",
    )
    parser.add_argument(
        "-p", "--plugin-module", action="append", default=[], metavar="MODULE",
        help="also know the message types this plugin module declares (repeatable); the log's own recipe is "
        "never imported",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    logs: list[Path] = args.log
    if len(logs) > 1 and (args.recipe or args.json):
        raise LogError(f"{'--recipe' if args.recipe else '--json'} takes one log, got {len(logs)}")
    if len(logs) == 1:
        return _inspect(logs[0], args)
    failed = []
    for log in logs:
        try:
            _inspect(log, args)
        except LogError as exc:  # say it and go on: one bad log does not hide the others
            print(f"slamfront: error: {printable(str(exc), keep_newlines=False)}")
            failed.append(log)
        print()
    if failed:
        raise LogError(f"{len(failed)} of {len(logs)} logs are damaged or invalid: {', '.join(map(str, failed))}")
    return 0


def _inspect(log: Path, args: argparse.Namespace) -> int:
    from slamfront.mcaplog.reader import embedded_recipe_text, log_file, summarize
    from slamfront.mcaplog.validate import validate_log
    from slamfront.trust import TRUST_FLAG

    path = log_file(log)
    if args.recipe:
        print(printable(embedded_recipe_text(path)), end="")
        return 0
    summary = summarize(path)
    if args.json:
        print(json.dumps(summary.to_dict(), indent=2))
    else:
        _print_summary(summary)
    valid = True
    if args.validate:
        # a damaged file is validated too: what can be read is checked, the damage listed
        validation = validate_log(path, types=_message_types(args.plugin_module))
        for problem in validation.problems:
            print(f"INVALID: {printable(problem, keep_newlines=False)}")
        for topic, schema in sorted(validation.not_installed.items()):
            print(f"not installed: {printable(topic)} ({printable(schema)}): no installed plugin declares this "
                  "message type; checked against the schema the log embeds")
        for field, why in _untrusted(path):
            print(f"note: the embedded recipe's {field} {printable(why, keep_newlines=False)}: "
                  f"replay refuses it without {TRUST_FLAG}")
        valid = validation.valid
        if valid:
            print(f"valid: {validation.n_messages} messages on {validation.n_topics} topics decoded")
    if not summary.complete:
        # what could be read is shown above; the exit status says the file is damaged
        raise LogError(f"{path}: {summary.problem}")
    if not valid:
        first = printable(shorten(validation.problems[0], 400), keep_newlines=False)
        raise LogError(f"{path}: {len(validation.problems)} problem(s) found by --validate, the first: {first}")
    return 0


def _message_types(modules: list[str]) -> MessageTypes:
    """The installed message types, with those of the modules named by ``-p``."""
    from slamfront.message_types import installed_message_types
    from slamfront.registry import PluginRegistry

    return PluginRegistry(modules=modules).message_types() if modules else installed_message_types()


def _untrusted(path: Path) -> list[tuple[str, str]]:
    from slamfront.mcaplog.reader import embedded_recipe_text
    from slamfront.recipe import load_yaml
    from slamfront.trust import untrusted_fields

    try:
        raw = load_yaml(embedded_recipe_text(path), f"{path}:recipe.yaml", LogError)
    except LogError:
        return []  # no (readable) recipe: nothing a replay would run
    return untrusted_fields(raw) if isinstance(raw, dict) else []


def _print_summary(summary: LogSummary) -> None:
    print(f"{printable(summary.path)}: {summary.size_bytes / 1e6:.2f} MB, {summary.n_messages} messages")
    if summary.start_ns is not None:
        print(f"time span: {(summary.end_ns - summary.start_ns) / 1e9:.3f} s")
    if not summary.complete:
        print(f"INCOMPLETE: only what could be read is listed ({printable(summary.problem or '', keep_newlines=False)})")
    width = min(max((len(t.topic) for t in summary.topics), default=5), 60)
    for topic in summary.topics:
        name, schema = printable(topic.topic, False), printable(topic.schema_name, False)
        print(f"  {name:<{width}}  {topic.count:>7}  {schema} ({printable(topic.message_encoding, False)})")
    for name, values in summary.metadata.items():
        shown = ", ".join(f"{k}={v}" for k, v in values.items())
        print(f"metadata {printable(name, False)}: {shorten(shown)}")
    if summary.attachments:
        print(f"attachments: {shorten(', '.join(summary.attachments), 400)}")
