#!/usr/bin/env python3
"""Reads a cmsckf MCAP log with the independent Python `mcap` reader.

Checks that every message decodes as JSON, that each channel has a JSON
schema, and prints message counts per topic and the last log time as JSON.
Exits 1 on a problem.
Usage: read_mcap.py [--seeking] [--validate] LOG.mcap

With --seeking it reads as PlotJuggler and Python's make_reader on a file
do: through the summary section and its chunk indexes, which a log must
have (a killed daemon's log has them only once `cmsckf log recover` has
rewritten it).

With --validate every message is checked against its channel's JSON schema
(the `jsonschema` package), and the report counts the messages checked.
"""
import json
import sys

from mcap.reader import SeekingReader, make_reader


def main() -> int:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    seeking = "--seeking" in sys.argv[1:]
    validate = "--validate" in sys.argv[1:]
    validators = {}
    checked = 0
    counts = {}
    last = 0
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
            if message.log_time != message.publish_time:
                print(f"{channel.topic}: log and publish time differ", file=sys.stderr)
                return 1
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            last = max(last, message.log_time)
        meta = [m.name for m in reader.iter_metadata()]
    report = {"library": header.library, "metadata": meta, "counts": counts, "last_log_time_ns": last}
    if validate:
        report["validated"] = checked
    print(json.dumps(report))
    return 0 if counts and "cmsckf" in meta else 1


if __name__ == "__main__":
    sys.exit(main())
