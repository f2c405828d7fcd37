"""
``sorter replay FILE.mcap``: what a recorded run holds, from the file alone.

Reads a recording of the cell (``sorter demo --record``, or the simulation node's
``record_path``) with the MCAP ROS 2 reader, which decodes every message from the
definitions embedded in the file (no ROS installation needed): the topics with
their types and counts, the simulated span, every parcel with its label, its exit
and (when the controller was recorded too) what the controller made of it, and a
PNG of the parcels' paths over the cell drawn from the recorded poses and the
cell's parameters stored in the file.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

from sorter_sim.outpaths import file_problem

METADATA = "sorter_sim parameters"  # written by the simulation node (sorter_sim.node)


def add_arguments(parser) -> None:
    parser.add_argument("recording", help="MCAP file written by sorter demo --record")
    parser.add_argument(
        "--out",
        default=None,
        metavar="PNG",
        help="draw the parcels' paths into this PNG (default: <recording>_paths.png)",
    )
    parser.add_argument("--no-plot", action="store_true", help="summarise only, draw nothing")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def read_recording(path: str | Path) -> dict:
    """
    Return what the recording holds.

    {"topics": {topic: {"type", "count"}}, "t_first_ns", "t_last_ns", "parcels":
    {id: {...}}, "paths": {id: [(x, y), ...]}, "cell": {parameter: value} or None}.
    Raises ValueError with one line when the file is no readable MCAP recording.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts: Counter = Counter()
    types: dict[str, str] = {}
    t_first = t_last = None
    outcomes: dict[int, dict] = {}
    confirmations: dict[str, dict] = {}
    paths: dict[int, list] = {}
    ids: list[int] | None = None
    cell = None
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for schema, channel, message, ros_msg in reader.iter_decoded_messages(
                log_time_order=True
            ):
                topic = channel.topic
                counts[topic] += 1
                types[topic] = schema.name
                t = message.log_time
                t_first = t if t_first is None else t_first
                t_last = t
                name = topic.rsplit("/", 2)[-2:]
                if name == ["sort", "outcomes"]:
                    values = {kv.key: kv.value for kv in ros_msg.values}
                    outcomes[int(values["id"])] = values
                elif name == ["sort", "confirmations"]:
                    values = {kv.key: kv.value for kv in ros_msg.values}
                    confirmations[values.get("label", ros_msg.name)] = values
                elif name == ["parcels", "ids"]:
                    ids = list(ros_msg.data)
                elif name == ["parcels", "poses"] and ids is not None:
                    if len(ids) == len(ros_msg.poses):
                        for pid, pose in zip(ids, ros_msg.poses):
                            paths.setdefault(int(pid), []).append(
                                (pose.position.x, pose.position.y)
                            )
            for record in reader.iter_metadata():
                if record.name == METADATA:
                    cell = {k: json.loads(v) for k, v in record.metadata.items() if k != "node"}
    except FileNotFoundError:
        raise ValueError(f"no such file: {str(path)[:200]!r}") from None
    except (McapError, EOFError, KeyError, ValueError, OSError) as exc:
        raise ValueError(f"{str(path)[:200]!r} is not a readable MCAP recording: {exc}") from None
    parcels = {}
    for pid in sorted(set(paths) | set(outcomes)):
        o = outcomes.get(pid, {})
        c = confirmations.get(o.get("label", ""), {})
        parcels[pid] = {
            "label": o.get("label", ""),
            "exit": o.get("exit", "in cell"),
            "t_exit_s": float(o["t"]) if "t" in o else None,
            "controller": c.get("result"),
            "destination_asked": c.get("destination_asked"),
        }
    return {
        "topics": {t: {"type": types[t], "count": counts[t]} for t in sorted(counts)},
        "t_first_ns": t_first,
        "t_last_ns": t_last,
        "parcels": parcels,
        "paths": paths,
        "cell": cell,
    }


def summarize(rec: dict) -> dict:
    """Return the summary of a recording read by ``read_recording`` (JSON-ready)."""
    exits = Counter(p["exit"] for p in rec["parcels"].values())
    results = Counter(p["controller"] for p in rec["parcels"].values() if p["controller"])
    span = (rec["t_last_ns"] - rec["t_first_ns"]) * 1e-9 if rec["t_first_ns"] is not None else 0.0
    return {
        "messages": sum(t["count"] for t in rec["topics"].values()),
        "topics": rec["topics"],
        "t_first_s": None if rec["t_first_ns"] is None else rec["t_first_ns"] * 1e-9,
        "t_last_s": None if rec["t_last_ns"] is None else rec["t_last_ns"] * 1e-9,
        "span_s": span,
        "parcels": len(rec["parcels"]),
        "exits": dict(sorted(exits.items())),
        "controller_results": dict(sorted(results.items())),
        "parcel_outcomes": {str(k): v for k, v in rec["parcels"].items()},
    }


def _print(s: dict, png: str | None) -> None:
    print(
        f"{s['messages']} messages on {len(s['topics'])} topics, simulated "
        f"{s['t_first_s'] or 0.0:.3f} .. {s['t_last_s'] or 0.0:.3f} s"
    )
    width = max([len(t) for t in s["topics"]] + [5])
    for topic, info in s["topics"].items():
        print(f"  {topic:<{width}}  {info['count']:>8}  {info['type']}")
    exits = ", ".join(f"{k} {v}" for k, v in s["exits"].items()) or "none"
    print(f"parcels: {s['parcels']} ({exits})")
    if s["controller_results"]:
        print("controller: " + ", ".join(f"{k} {v}" for k, v in s["controller_results"].items()))
    for pid, p in s["parcel_outcomes"].items():
        t = "" if p["t_exit_s"] is None else f" at {p['t_exit_s']:.3f} s"
        ctl = f" ({p['controller']}, asked {p['destination_asked']})" if p["controller"] else ""
        print(f"  {pid:>5} {p['label']:<12} {p['exit']}{t}{ctl}")
    if png:
        print(f"paths: {png}")


def run(args) -> int | str:
    """``sorter replay``."""
    png = None
    if not args.no_plot:
        png = args.out or str(Path(args.recording).with_suffix("")) + "_paths.png"
        if Path(png).suffix.lower() != ".png":
            return f"--out must name a .png file, got {png[:200]!r}"
        problem = file_problem(Path(png))
        if problem:
            return problem
    try:
        rec = read_recording(args.recording)
    except ValueError as exc:
        return f"sorter replay: {exc}"
    s = summarize(rec)
    if png:
        if rec["cell"] is None:
            return "sorter replay: the recording holds no cell parameters to draw the cell from"
        from sorter_cell.demo import plot_paths

        title = (
            f"replay of {Path(args.recording).name}: {s['parcels']} parcels, "
            f"{s['span_s']:.1f} s simulated"
        )
        exit_of = {pid: p["exit"] for pid, p in rec["parcels"].items()}
        plot_paths(rec["paths"], exit_of, rec["cell"], title, Path(png))
    if args.json:
        s["png"] = png
        print(json.dumps(s, sort_keys=True, allow_nan=False, default=_nan_none))
    else:
        _print(s, png)
    return 0


def _nan_none(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    raise TypeError(type(obj).__name__)
