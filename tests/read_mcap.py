#!/usr/bin/env python3
"""Reads a cmsckf MCAP log with the independent Python `mcap` reader.

Checks that every message decodes as JSON, that each channel has a JSON
schema, and prints message counts per topic as JSON. Exits 1 on a problem.
Usage: read_mcap.py LOG.mcap
"""
import json
import sys

from mcap.reader import make_reader


def main() -> int:
    counts = {}
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        for schema, channel, message in reader.iter_messages():
            if schema is None or schema.encoding != "jsonschema":
                print(f"channel {channel.topic}: no JSON schema", file=sys.stderr)
                return 1
            json.loads(message.data)
            if message.log_time != message.publish_time:
                print(f"{channel.topic}: log and publish time differ", file=sys.stderr)
                return 1
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        meta = [m.name for m in reader.iter_metadata()]
    print(json.dumps({"library": header.library, "metadata": meta, "counts": counts}))
    return 0 if counts and "cmsckf" in meta else 1


if __name__ == "__main__":
    sys.exit(main())
