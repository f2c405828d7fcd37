"""
``sorter replay FILE.mcap``: what a recorded run holds, from the file alone.

Reads a recording of the cell (``sorter demo --record``, or the simulation node's
``record_path``) with the MCAP ROS 2 reader, which decodes every message from the
definitions embedded in the file (no ROS installation needed): the topics with
their types and counts, the simulated span, every parcel with its label, its exit
and (when the controller was recorded too) what the controller made of it, and a
PNG of the parcels' paths over the cell drawn from the recorded poses and the
cell's parameters stored in the file. A recording of a cell under ``contact: rigid``
holds its ``contacts`` too: how many periods' contacts, the most points at once and the
largest normal force between two bodies, which; a recording without them reads as before.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

from sorter_ros.outcomes import parse_contact_text, values
from sorter_sim.studies.outpaths import file_problem

METADATA = "sorter_sim parameters"  # written by the simulation node (sorter_sim.frontends.node)


def add_arguments(parser) -> None:
    """
    Add the verb's arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    parser.add_argument("recording", help="MCAP file written by sorter demo --record")
    parser.add_argument(
        "--out",
        default=None,
        metavar="PNG",
        help="draw the parcels' paths into this PNG (default: <recording>_paths.png)",
    )
    parser.add_argument("--no-plot", action="store_true", help="summarise only, draw nothing")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument(
        "--recover",
        action="store_true",
        help="read a torn or damaged file up to its last intact chunk (what is lost is said)",
    )


RECORD_SIZE_LIMIT = 256 * 1024 * 1024  # no record of ours comes near; a flipped length may


def read_recording(path: str | Path) -> dict:
    """
    Return what the recording holds, reading it as a stream from its first byte.

    {"topics": {topic: {"type", "count"}}, "t_first_ns", "t_last_ns", "parcels":
    {id: {...}}, "paths": {id: [(x, y), ...]}, "cell": {parameter: value} or None,
    "damage": None or what is wrong with the file and where, "undecodable": {topic:
    count}}. Chunk and data-section CRCs are checked: a torn file (the process killed,
    the disk full) or a damaged one is read up to its last intact chunk and the damage
    is named; a record outside a chunk is taken only once the data section's CRC has
    vouched for it, so a damaged opcode never adds a message; messages whose schema
    cannot be decoded are counted, not decoded.
    Raises ValueError with one line when nothing of the file is a readable recording.

    Parameters
    ----------
    path : str or Path
        The MCAP recording.

    Returns
    -------
    dict
        What the recording holds.

    """
    from mcap.records import (
        Channel,
        Chunk,
        DataEnd,
        Footer,
        Message,
        Metadata,
        Schema,
        Statistics,
    )
    from mcap.stream_reader import StreamReader

    from sorter_cell.recover import chunk_records

    state = _Reading()
    try:
        size = Path(path).stat().st_size
        f = open(path, "rb")
    except FileNotFoundError:
        raise ValueError(f"no such file: {str(path)[:200]!r}") from None
    except OSError as exc:
        raise ValueError(f"cannot read {str(path)[:200]!r}: {exc.strerror or exc}") from None
    stats = None
    finished = False
    in_data = True
    with f:
        try:
            reader = StreamReader(
                f, emit_chunks=True, validate_crcs=True, record_size_limit=RECORD_SIZE_LIMIT
            )
            for record in reader.records:
                if isinstance(record, Chunk) and in_data:
                    # its CRC (when its writer wrote one) is checked before a record is taken;
                    # a chunk holds only schemas, channels and messages, no index to mistake;
                    # it is inflated only up to a bound, whatever size it states
                    for inner in chunk_records(record):
                        state.take(inner, vouched=True)
                elif isinstance(record, (Schema, Channel, Message)) and in_data:
                    # outside a chunk only the data section's CRC, at DataEnd, vouches for
                    # it: a damaged opcode (a MessageIndex read as a Message) looks the same
                    state.take(record, vouched=False)
                elif isinstance(record, Metadata) and record.name == METADATA:
                    state.metadata(record.metadata)
                elif isinstance(record, DataEnd):
                    in_data = False
                    state.vouch_all()  # the reader has checked the data section's CRC, if any
                elif isinstance(record, Statistics):
                    stats = record
                elif isinstance(record, Footer):
                    finished = True
        except Exception as exc:  # whatever a damaged byte makes the parser do
            where = f"at byte {f.tell()} of {size}"
            what = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
            if state.n_records == 0 and not state.schemas and not state.pending:
                raise ValueError(
                    f"{str(path)[:200]!r} is not a readable MCAP recording: {what}"
                ) from None
            unvouched = state.drop_unvouched()
            if type(exc).__name__ == "EndOfFile" or f.tell() >= size:
                state.damage = (
                    f"the file ends at byte {size} in the middle of a record, without its "
                    "summary (cut short: the recorder was killed or its disk filled); "
                    f"{state.n_records} messages in complete chunks were read"
                )
            else:
                state.damage = (
                    f"the file breaks off {where} ({type(exc).__name__}: {what}); "
                    f"{state.n_records} messages before it were read, the rest is lost"
                )
            if unvouched:
                state.damage += (
                    f"; {unvouched} messages outside chunks, which no CRC vouches for, "
                    "were left out"
                )
    if state.damage is None and not finished:
        state.drop_unvouched()
        state.damage = (
            f"the file ends at byte {size} without its summary (cut short: the recorder was "
            f"killed or its disk filled); {state.n_records} messages were read"
        )
    if state.damage is None and stats is not None and stats.message_count != state.n_records:
        state.damage = (
            f"the summary counts {stats.message_count} messages, the data holds {state.n_records}"
        )
    return state.result()


class _Reading:
    """What ``read_recording`` gathers record by record, robust to any content."""

    def __init__(self):
        self.schemas: dict = {}
        self.channels: dict = {}
        self.decoders: dict = {}
        self.counts: Counter = Counter()
        self.types: dict[str, str] = {}
        self.undecodable: Counter = Counter()
        self.t_first = self.t_last = None
        self.outcomes: dict[int, dict] = {}
        self.confirmations: dict[str, dict] = {}
        self.paths: dict[int, list] = {}
        self.ids: list[int] | None = None
        self.contacts: dict | None = None  # the contacts topic's figures, once one is read
        self.cell = None
        self.damage: str | None = None
        self.n_records = 0
        # records taken in file order but held until a CRC vouches for them: once one
        # is held, the vouched ones after it wait too, so that order is kept
        self.pending: list[tuple[object, bool]] = []

    def take(self, record, vouched: bool) -> None:
        """Take a Schema, Channel or Message record now, or hold it until vouched for."""
        if vouched and not self.pending:
            self._apply(record)
        else:
            self.pending.append((record, vouched))

    def vouch_all(self) -> None:
        """Take every held record: a CRC over all of them has been checked."""
        held, self.pending = self.pending, []
        for record, _ in held:
            self._apply(record)

    def drop_unvouched(self) -> int:
        """Take the held records a chunk CRC vouched for, drop the others: their message count."""
        from mcap.records import Message

        held, self.pending = self.pending, []
        dropped = 0
        for record, vouched in held:
            if vouched:
                self._apply(record)
            else:
                dropped += isinstance(record, Message)
        return dropped

    def _apply(self, record) -> None:
        from mcap.records import Channel, Schema

        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channels[record.id] = record
        else:
            self.message(record)

    def _decoder(self, channel):
        from mcap_ros2.decoder import DecoderFactory

        key = channel.schema_id
        if key not in self.decoders:
            schema = self.schemas.get(key)
            try:
                self.decoders[key] = DecoderFactory().decoder_for(channel.message_encoding, schema)
            except Exception:  # a schema the decoder cannot build (recursive, wstring...)
                self.decoders[key] = None
        return self.decoders[key]

    def message(self, record) -> None:
        self.n_records += 1
        channel = self.channels.get(record.channel_id)
        topic = channel.topic if channel is not None else f"<channel {record.channel_id}>"
        self.counts[topic] += 1
        schema = self.schemas.get(channel.schema_id) if channel is not None else None
        self.types[topic] = schema.name if schema is not None else "?"
        t = record.log_time
        self.t_first = t if self.t_first is None else min(self.t_first, t)
        self.t_last = t if self.t_last is None else max(self.t_last, t)
        decode = self._decoder(channel) if channel is not None else None
        try:
            msg = decode(record.data)
        except Exception:
            msg = None
        if msg is None:
            self.undecodable[topic] += 1
            return
        try:
            self._take(topic, msg)
        except (AttributeError, KeyError, TypeError, ValueError, OverflowError):
            self.undecodable[topic] += 1

    def _take(self, topic: str, msg) -> None:
        name = topic.rsplit("/", 2)[-2:]
        if name == ["sort", "outcomes"]:
            v = values(msg)
            self.outcomes[int(v["id"])] = v
        elif name == ["sort", "confirmations"]:
            v = values(msg)
            self.confirmations[v.get("label", msg.name)] = v
        elif name[-1] == "contacts":
            self._take_contacts(msg)
        elif name == ["parcels", "ids"]:
            self.ids = [int(i) for i in msg.data]
        elif name == ["parcels", "poses"] and self.ids is not None:
            if len(self.ids) == len(msg.poses):
                for pid, pose in zip(self.ids, msg.poses):
                    self.paths.setdefault(pid, []).append(
                        (float(pose.position.x), float(pose.position.y))
                    )

    def _take_contacts(self, msg) -> None:
        """
        Take one period's contact markers (``contact_markers``): count, most points, peak.

        The peak is the largest normal force between two bodies, summed over their points
        (a face in contact has two, whose split is the solver's; their sum is the load).
        """
        points = [parse_contact_text(m.text) for m in msg.markers if m.action == 0]
        pairs: dict = {}
        for first, second, force in points:
            pairs[first, second] = pairs.get((first, second), 0.0) + force
        c = self.contacts
        if c is None:
            c = self.contacts = {
                "frames": 0,
                "most_points": 0,
                "largest_force_n": 0.0,
                "largest_between": None,
            }
        c["frames"] += 1
        c["most_points"] = max(c["most_points"], len(points))
        for (first, second), force in pairs.items():
            if math.isfinite(force) and force > c["largest_force_n"]:
                c["largest_force_n"] = force
                c["largest_between"] = f"{first} | {second}"

    def metadata(self, values: dict) -> None:
        try:
            self.cell = {k: json.loads(v) for k, v in values.items() if k != "node"}
        except (TypeError, ValueError):
            self.cell = None

    def result(self) -> dict:
        parcels = {}
        for pid in sorted(set(self.paths) | set(self.outcomes)):
            o = self.outcomes.get(pid, {})
            c = self.confirmations.get(o.get("label", ""), {})
            parcels[pid] = {
                "label": o.get("label", ""),
                "exit": o.get("exit", "in cell"),
                "t_exit_s": _seconds(o.get("t")),
                "controller": c.get("result"),
                "destination_asked": c.get("destination_asked"),
            }
        return {
            "topics": {
                t: {"type": self.types[t], "count": self.counts[t]} for t in sorted(self.counts)
            },
            "t_first_ns": self.t_first,
            "t_last_ns": self.t_last,
            "parcels": parcels,
            "paths": self.paths,
            "cell": self.cell,
            "damage": self.damage,
            "undecodable": dict(sorted(self.undecodable.items())),
            "contacts": self.contacts,
        }


def _seconds(text) -> float | None:
    """Return a recorded time [s], or None when it is missing or not a finite number."""
    try:
        t = float(text)
    except (TypeError, ValueError):
        return None
    return t if math.isfinite(t) else None


def summarize(rec: dict) -> dict:
    """
    Return the summary of a recording read by ``read_recording`` (JSON-ready).

    Parameters
    ----------
    rec : dict
        A recording read by ``read_recording``.

    Returns
    -------
    dict
        The summary (JSON-ready).

    """
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
        "damage": rec.get("damage"),
        "undecodable": rec.get("undecodable", {}),
        "contacts": rec.get("contacts"),
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
    c = s.get("contacts")
    if c:
        between = f" ({c['largest_between']})" if c["largest_between"] else ""
        print(
            f"contacts: {c['frames']} periods recorded, up to {c['most_points']} points, "
            f"largest normal force {c['largest_force_n']:.1f} N{between}"
        )
    if s.get("undecodable"):
        print(
            "undecodable: "
            + ", ".join(f"{t} {n}" for t, n in s["undecodable"].items())
            + " (their schema or data could not be decoded)"
        )
    if s.get("damage"):
        print(f"damage: {s['damage']}")
    if png:
        print(f"paths: {png}")


def run(args) -> int | str:
    """
    ``sorter replay``.

    Parameters
    ----------
    args : list of str or argparse.Namespace
        The command line, or the parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input (exit 2).

    """
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
        return str(exc)
    if rec["damage"] and not args.recover:
        n = sum(t["count"] for t in rec["topics"].values())
        return (
            f"{str(args.recording)[:200]!r} is damaged: {rec['damage']}; "
            f"--recover reads the {n} messages before the damage"
        )
    s = summarize(rec)
    if png:
        if rec["cell"] is None:
            return "the recording holds no cell parameters to draw the cell from"
        from sorter_cell.demo_summary import plot_paths

        title = (
            f"replay of {Path(args.recording).name}: {s['parcels']} parcels, "
            f"{s['span_s']:.1f} s simulated"
        )
        exit_of = {pid: p["exit"] for pid, p in rec["parcels"].items()}
        try:
            plot_paths(rec["paths"], exit_of, rec["cell"], title, Path(png))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            return (
                "the recorded cell parameters cannot be drawn "
                f"({type(exc).__name__}: {str(exc)[:120]}); --no-plot summarises without them"
            )
    if args.json:
        s["png"] = png
        print(json.dumps(_finite(s), sort_keys=True, allow_nan=False))
    else:
        _print(s, png)
    return 0


def _finite(obj):
    """Return ``obj`` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj
