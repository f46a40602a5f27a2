"""``bptsb bag``: inspect and repair rosbag2 MCAP bags (``info``, ``recover``)."""

from __future__ import annotations

import argparse
import json

NAME = "bag"
HELP = (
    "Inspect or repair a rosbag2 MCAP bag (a directory with metadata.yaml and <name>_0.mcap, or one .mcap file).\n"
    "  info BAG      topics, types, message counts, duration, start/end, size, chunks (like `ros2 bag info`);\n"
    "                lists chunks that fail their CRC check\n"
    "  recover BAG   rebuild a killed or damaged bag: keeps every intact chunk (resynchronising past damaged\n"
    "                records), reports what was dropped, rewrites the .mcap with indexes and summary (the\n"
    "                damaged file is kept as <file>.damaged, .damaged.1, ...: never overwritten) and rebuilds\n"
    "                a missing, unreadable or inconsistent metadata.yaml\n"
    "Example: bptsb bag info bags/lissajous_closed_example (the example bag of a source checkout; installed, it is "
    "bptsb_ros.files.package_data.example_bag())"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bag_command", required=True, metavar="ACTION")
    info = sub.add_parser("info", help="show what a bag holds, like `ros2 bag info`")
    info.add_argument("bag", help="bag directory or .mcap file")
    info.add_argument("--json", action="store_true", help="print the information as JSON")
    recover = sub.add_parser("recover", help="rebuild a bag left unfinished by a killed recorder or damaged")
    recover.add_argument("bag", help="bag directory (or its .mcap file)")
    recover.add_argument("--delete-damaged", action="store_true",
                         help="delete the damaged original instead of keeping it as <file>.damaged")


def _info(args: argparse.Namespace) -> int:
    from bptsb_ros.bags.reader import bag_info, format_info

    info = bag_info(args.bag)
    if not args.json:
        print(format_info(info))
        return 0
    print(json.dumps({
        "path": str(info.path),
        "files": [str(f) for f in info.files],
        "size_bytes": info.size_bytes,
        "storage_identifier": info.storage_identifier,
        "ros_distro": info.ros_distro,
        "start_ns": info.start_ns,
        "end_ns": info.end_ns,
        "duration_ns": info.duration_ns,
        "message_count": info.message_count,
        "chunk_count": info.chunk_count,
        "chunk_compressions": info.chunk_compressions,
        "topics": [
            {"name": t.name, "type": t.msgtype, "message_count": t.message_count,
             "serialization_format": t.serialization_format, "type_description_hash": t.type_description_hash,
             "offered_qos_profiles": [q.to_dict() for q in t.offered_qos_profiles]}
            for t in info.topics
        ],
        "dropped_messages": info.dropped_messages,
        "dropped_by_topic": info.dropped_by_topic,
        "recording_complete": info.recording_complete,
        "publishers": [
            {"topic": c.topic, "count": c.count,
             **({"gid": c.publisher.gid, "node": c.publisher.node, "namespace": c.publisher.namespace}
                if c.publisher else {"gid": None})}
            for c in info.publishers
        ],
    }, indent=2))
    return 0


def _recover(args: argparse.Namespace) -> int:
    from bptsb_ros.bags.recover import recover_bag

    report = recover_bag(args.bag, keep_damaged=not args.delete_damaged)
    print(report.summary())
    return 0


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.bags.errors import BagError
    from bptsb_ros.cli.options import fail

    try:
        return _recover(args) if args.bag_command == "recover" else _info(args)
    except BagError as exc:  # a missing, unreadable or damaged bag
        return fail(f"{NAME} {args.bag_command}", exc)
    except OSError as exc:  # recover: the bag's directory is not writable
        return fail(f"{NAME} {args.bag_command}", f"{exc.filename or args.bag}: {exc.strerror or exc}")
