#!/usr/bin/env python3
"""Reads a cmsckf MCAP log with the independent Python `mcap` reader.

Checks that every message decodes as JSON, that each channel has a JSON
schema, and prints message counts per topic and the last log time as JSON.
Exits 1 on a problem.
Usage: read_mcap.py [--seeking] [--validate] [--layout LAYOUT.json] LOG.mcap

With --seeking it reads as PlotJuggler and Python's make_reader on a file
do: through the summary section and its chunk indexes, which a log must
have (a killed daemon's log has them only once `cmsckf log recover` has
rewritten it).

With --validate every message is checked against its channel's JSON schema
(the `jsonschema` package), and the report counts the messages checked.

With --layout, every topic a Foxglove layout names (docs/foxglove-layout.json)
must be a channel of the log, and every Plot message path (`/topic.field[i]`)
must lead to a number in at least one of that topic's messages; the report
lists the paths checked.
"""
import json
import re
import sys

from mcap.reader import SeekingReader, make_reader


def layout_refs(node, topics, paths):
    """Collects the topics and Plot paths a layout names, anywhere in it."""
    if isinstance(node, dict):
        for k, v in node.items():
            if k in ("followTopic", "topicToRender", "topicPath") and isinstance(v, str):
                topics.add(v)
            elif k == "topics" and isinstance(v, dict):
                topics.update(t for t in v if t.startswith("/"))
            elif k == "paths" and isinstance(v, list):
                paths.update(p["value"] for p in v if isinstance(p, dict) and "value" in p)
            layout_refs(v, topics, paths)
    elif isinstance(node, list):
        for v in node:
            layout_refs(v, topics, paths)


def resolve(value, steps):
    """Follows `.field` and `[i]` steps into a decoded message."""
    for kind, key in steps:
        if kind == "." and isinstance(value, dict) and key in value:
            value = value[key]
        elif kind == "[" and isinstance(value, list) and int(key) < len(value):
            value = value[int(key)]
        else:
            return None
    return value


def steps_of(rest):
    """`.a[0].b` -> [(".", "a"), ("[", "0"), (".", "b")]."""
    return re.findall(r"([.\[])([A-Za-z_0-9]+)\]?", rest)


def main() -> int:
    argv = sys.argv[1:]
    layout_path = None
    if "--layout" in argv:
        i = argv.index("--layout")
        layout_path = argv[i + 1]
        del argv[i : i + 2]
    args = [a for a in argv if not a.startswith("--")]
    seeking = "--seeking" in sys.argv[1:]
    validate = "--validate" in sys.argv[1:]
    validators = {}
    checked = 0
    counts = {}
    last = 0
    unix_stamped = 0
    layout_topics, layout_paths, found = set(), set(), set()
    if layout_path:
        with open(layout_path, encoding="utf-8") as f:
            layout = json.load(f)
        sdk = layout.get("version") == 1 and "content" in layout
        desktop = isinstance(layout.get("configById"), dict) and "layout" in layout
        if not (sdk or desktop):
            print(f"{layout_path}: neither a Foxglove desktop layout nor an SDK one", file=sys.stderr)
            return 1
        layout_refs(layout, layout_topics, layout_paths)
    with open(args[0], "rb") as f:
        if seeking:
            reader = SeekingReader(f)
            summary = reader.get_summary()
            if summary is None or not summary.chunk_indexes:
                print("no summary with chunk indexes", file=sys.stderr)
                return 1
        else:
            reader = make_reader(f)
        header = reader.get_header()
        for schema, channel, message in reader.iter_messages():
            if schema is None or schema.encoding != "jsonschema":
                print(f"channel {channel.topic}: no JSON schema", file=sys.stderr)
                return 1
            value = json.loads(message.data)
            if validate:
                import jsonschema

                if schema.id not in validators:
                    doc = json.loads(schema.data)
                    cls = jsonschema.validators.validator_for(doc, default=jsonschema.Draft202012Validator)
                    cls.check_schema(doc)
                    validators[schema.id] = cls(doc)
                errors = list(validators[schema.id].iter_errors(value))
                if errors:
                    print(f"{channel.topic}: {errors[0].message} at {list(errors[0].path)}", file=sys.stderr)
                    return 1
                checked += 1
            # Log time is Unix time (from the autopilot's SYSTEM_TIME) and
            # publish time its boot time; before SYSTEM_TIME, both boot time.
            offset = message.log_time - message.publish_time
            if offset != 0 and not (1_000_000_000 * 10**9 < offset < 4_000_000_000 * 10**9):
                print(f"{channel.topic}: log time is neither boot nor Unix time ({offset} ns apart)", file=sys.stderr)
                return 1
            unix_stamped += offset != 0
            for path in layout_paths - found:
                prefix = channel.topic + "."
                if path.startswith(prefix) and isinstance(resolve(value, steps_of(path[len(prefix) - 1 :])), (int, float)):
                    found.add(path)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            last = max(last, message.publish_time)
        meta = [m.name for m in reader.iter_metadata()]
    report = {
        "library": header.library,
        "metadata": meta,
        "counts": counts,
        "last_publish_time_ns": last,
        "unix_stamped": unix_stamped,
    }
    if validate:
        report["validated"] = checked
    if layout_path:
        missing_topics = sorted(t for t in layout_topics if t not in counts)
        missing_paths = sorted(layout_paths - found)
        report["layout_topics"] = sorted(layout_topics)
        report["layout_paths"] = sorted(found)
        if missing_topics or missing_paths:
            print(f"layout names topics not in the log {missing_topics} or paths to no number {missing_paths}", file=sys.stderr)
            return 1
    print(json.dumps(report))
    return 0 if counts and "cmsckf" in meta else 1


if __name__ == "__main__":
    sys.exit(main())
