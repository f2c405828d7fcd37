"""
What ``sorter demo`` reports: the summary of a run, its exit code, its table and its picture.

``summarize`` turns what the demo's observer saw (outcomes, confirmations, the
cell's diagnostics, the parcels' paths) into the summary every ``--io`` prints;
``exit_code`` says whether the run was clean; ``print_table`` and ``plot_paths``
show it.
"""

from __future__ import annotations

import sys
from pathlib import Path


# outcome colours on the plot
EXIT_COLOURS = {"left": "tab:green", "right": "tab:blue", "straight": "0.45", "jammed": "tab:red"}


def summarize(obs, plan: dict, sim_time: float, wall: float, time_mode: str) -> dict:
    """
    Return the demo's summary.

    Parameters
    ----------
    obs : _Observer
        What the demo's observer saw.
    plan : dict
        The stream plan (``stream_plan``).
    sim_time : float
        Simulated seconds.
    wall : float
        The wall time it took [s].
    time_mode : str
        fast or realtime.

    Returns
    -------
    dict
        The summary (JSON-ready).

    """
    exits = {"left": 0, "right": 0, "straight": 0, "jammed": 0}
    mis_sorted, untracked = [], 0
    flagged = {"gap_too_short": 0, "late": 0, "cannot_divert": 0, "fault": 0, "not_executing": 0}
    rejected = 0
    for label, o in obs.outcomes.items():
        exits[o["exit"]] = exits.get(o["exit"], 0) + 1
        c = obs.confirmations.get(label)
        if c is None:
            untracked += 1  # on the belt before the controller was tracking
            continue
        result = c["result"]
        if result in flagged:
            flagged[result] += 1
        if result == "rejected":
            rejected += 1
        intended = (
            c["destination_asked"]
            if result in ("sorted", "rejected", "mis-sorted", "missed")
            else "straight"
        )
        if o["exit"] != "jammed" and o["exit"] != intended:
            mis_sorted.append(label)
    left_cell = exits["left"] + exits["right"] + exits["straight"]
    d = obs.ctl_diag
    mean = plan["mean_length_m"]
    cell_capacity = 3600.0 * plan["belt_speed"] / (mean + plan["min_gap_m"])
    return {
        "sim_time_s": round(sim_time, 3),
        "wall_s": round(wall, 3),
        "real_time_factor": round(sim_time / wall, 3) if wall > 0 else None,
        "time_mode": time_mode,
        "inducted": len(obs.ids_seen),
        "sorted_left": exits["left"],
        "sorted_right": exits["right"],
        "straight": exits["straight"],
        "straight_flagged": sum(flagged.values()),
        "flagged": flagged,
        "rejected": rejected,
        "mis_sorted": len(mis_sorted),
        "mis_sorted_labels": mis_sorted[:20],
        "jams": exits["jammed"],
        "untracked": untracked,
        "in_cell_at_end": len(obs.ids_seen) - sum(exits.values()),
        "throughput_pcs_h": round(3600.0 * left_cell / sim_time, 1) if sim_time > 0 else 0.0,
        "diverted_pcs_h": round(3600.0 * (exits["left"] + exits["right"]) / sim_time, 1)
        if sim_time > 0
        else 0.0,
        "model_capacity_pcs_h": round(plan["seed_capacity_pcs_h"], 1),
        "cell_capacity_pcs_h": round(cell_capacity, 1),
        "min_gap_m": round(plan["min_gap_m"], 3),
        "stream_gap_m": plan["stream_gap_m"],
        "contact": plan.get("contact", "jam"),
        "mean_parcel_length_m": mean,
        "controller_state": d.get("state", "unknown"),
        "controller_faults": {
            k[6:]: int(v) for k, v in d.items() if k.startswith("fault_") and v != "0"
        },
        "late_decisions": int(d.get("late", 0)),
        "scan_wall_p99_ms": float(d.get("scan_wall_p99_ms", "nan")),
    }


def exit_code(summary: dict) -> int:
    """
    Return the demo's exit code: 0 for a clean run, 1 otherwise.

    Clean: nothing mis-sorted, no jam, and the controller running at the end (a
    controller that faulted and stayed faulted sorts nothing, whatever the counts say).

    Parameters
    ----------
    summary : dict
        The demo's summary.

    Returns
    -------
    int
        0 for a clean run, 1 otherwise.

    """
    if summary["mis_sorted"] or summary["jams"]:
        return 1
    if summary.get("controller_state", "running") not in ("running", "unknown"):
        print(
            f"sorter demo: the controller ended {summary['controller_state']!r} "
            f"(faults: {summary.get('controller_faults') or 'none counted'})",
            file=sys.stderr,
        )
        return 1
    return 0


def print_table(s: dict) -> None:
    """
    Print the demo's summary as a table.

    Parameters
    ----------
    s : dict
        The summary.

    """
    rows = [
        (
            "simulated time",
            f"{s['sim_time_s']:.1f} s in {s['wall_s']:.1f} s wall "
            f"(real-time factor {s['real_time_factor']:.2f}, {s['time_mode']})",
        ),
        ("inducted", s["inducted"]),
        ("sorted left", s["sorted_left"]),
        ("sorted right", s["sorted_right"]),
        (
            "straight",
            f"{s['straight']}  (of which sent straight by the controller: "
            f"{s['straight_flagged']}; rejected: {s['rejected']})",
        ),
        ("mis-sorted", s["mis_sorted"]),
        ("jams", s["jams"]),
        ("still in the cell", s["in_cell_at_end"]),
        (
            "throughput",
            f"{s['throughput_pcs_h']:.0f} pcs/h ({s['diverted_pcs_h']:.0f} pcs/h diverted)",
        ),
        (
            "model capacity",
            f"{s['model_capacity_pcs_h']:.0f} pcs/h (seed W_t = 3600/t_scrap, "
            f"A = {s['mean_parcel_length_m']:g} m)",
        ),
        (
            "cell capacity",
            f"{s['cell_capacity_pcs_h']:.0f} pcs/h at the least mixed-stream gap "
            f"{s['min_gap_m']:.3f} m",
        ),
        ("stream gap", f"{s['stream_gap_m'][0]:.3f} .. {s['stream_gap_m'][1]:.3f} m"),
        (
            "contact",
            "rigid (parcels push and ride on as rigid boxes; a jam is one that makes no progress)"
            if s.get("contact") == "rigid"
            else "jam (two parcels that touch stop and jam)",
        ),
        (
            "controller",
            f"{s['controller_state']}; late decisions {s['late_decisions']}; "
            f"scan p99 {s['scan_wall_p99_ms']:.2f} ms wall",
        ),
    ]
    width = max(len(r[0]) for r in rows)
    how = f"a soft PLC over {s['io']}" if s.get("io") else "its controller over ROS 2"
    print(f"sorter demo: the cell and {how}")
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")


def exits_by_id(outcomes) -> dict[int, str]:
    """
    Return {parcel id: exit} from outcome values (the cell's sort/outcomes key/values).

    Parameters
    ----------
    outcomes : list
        The outcomes' key/values.

    Returns
    -------
    dict
        {parcel id: exit}.

    """
    exit_of = {}
    for o in outcomes:
        try:
            exit_of[int(o["id"])] = o["exit"]
        except (KeyError, ValueError):
            pass
    return exit_of


def plot_paths(
    paths: dict[int, list], exit_of: dict[int, str], params: dict, title: str, out: Path
) -> None:
    """
    Draw the parcels' paths over the cell, coloured by their exit, into the PNG ``out``.

    ``paths``: {parcel id: [(x, y), ...]} in the conveyor frame [m]; ``params``: the cell's
    belt_width, disk_field_length, chute_margin, induct_x, exit_x and photo-eyes.

    Parameters
    ----------
    paths : dict
        {parcel id: its path}.
    exit_of : dict
        {parcel id: exit}.
    params : dict
        The cell's parameters (``cell_params``).
    title : str
        The picture's title.
    out : Path
        The PNG.

    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    w, b, margin = params["belt_width"], params["disk_field_length"], params["chute_margin"]
    x0, x1 = params["induct_x"] - 0.2, params["exit_x"] + 0.3
    fig, ax = plt.subplots(figsize=(11, 4.2))
    ax.add_patch(Rectangle((x0, -w / 2), x1 - x0, w, color="0.93", zorder=0))
    ax.add_patch(
        Rectangle(
            (0.0, -w / 2), b, w, color="tab:orange", alpha=0.18, zorder=0, label="disk field"
        )
    )
    for side in (1, -1):
        ax.plot([x0, -margin], [side * w / 2] * 2, color="k", lw=2)
        ax.plot([b + margin, x1], [side * w / 2] * 2, color="k", lw=2)
    for name, x in zip(params["photo_eyes.names"], params["photo_eyes.x"]):
        ax.plot([x, x], [-w / 2, w / 2], color="tab:purple", lw=0.8, ls="--")
        ax.text(x, -w / 2 - 0.08, name, ha="center", va="top", fontsize=7, color="tab:purple")
    seen = set()
    for pid, pts in paths.items():
        if len(pts) < 2:
            continue
        ex = exit_of.get(pid, "in cell")
        colour = EXIT_COLOURS.get(ex, "k")
        xs, ys = zip(*pts)
        ax.plot(xs, ys, color=colour, lw=0.8, alpha=0.7, label=None if ex in seen else ex)
        seen.add(ex)
    ax.set_xlim(x0, x1)
    ax.set_ylim(-w / 2 - 0.45, w / 2 + 0.45)
    ax.set_aspect("equal")
    ax.set_xlabel("x along the belt [m] (conveyor frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=7, ncol=6, frameon=False)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=130)
    plt.close(fig)
