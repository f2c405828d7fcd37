"""
The model's command line: ``run | paper | sweep | study | bench`` (``python -m sorter_sim``).

The ``sorter`` command (``sorter_cell.cli``) is this plus ``demo``, which starts
the controller too and so lives above both packages. Each verb lives in its own
module exposing ``add_arguments(parser)`` and
``run(args) -> int | str | None`` (ros2cli style: a returned string is an error
message, printed as one line with exit code 2). This module only dispatches, so a
verb whose module is missing from an installation does not break the others.
Bad input never ends in a traceback: ``SceneError``/``ValueError`` raised by a
verb become one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys

from sorter_ros.env import apply_ros_env_defaults
from sorter_sim.model.compile_progress import set_quiet as set_compile_quiet

# The model (numba, the kernels' cache), SciPy and rclpy load with the verb that needs
# them, not before the command line is read: ``sorter --help``, a usage error or a
# verb that needs less starts in a fraction of a second, not the two a full import takes.

# verb -> (module, one-line help)
VERBS = {
    "run": (__name__, "run one parcel through one scene and print the result"),
    "paper": ("sorter_sim.studies.paper_cli", "regenerate the seed's figures (data + PNG)"),
    "sweep": ("sorter_sim.studies.sweep", "run a design study over scene keys"),
    "study": ("sorter_sim.studies.study_cli", "design studies beyond the seed (best-alpha)"),
    "bench": ("sorter_sim.studies.bench", "benchmarks and the work-precision report"),
}


class _Parser(argparse.ArgumentParser):
    """argparse that exits with code 2 and one line, as usage errors should."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """
    Add ``sorter run``'s arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    from sorter_sim.studies.scene_args import add_scene_options

    parser.add_argument("scene", help="scene YAML file (see config/scenes/)")
    add_scene_options(parser)


def _fmt(value, unit="", digits=6):
    if value is None:
        return "never"
    return f"{value:.{digits}g}{unit}"


def _json_safe(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def run(args) -> int | str:
    """
    Run ``sorter run``.

    Parameters
    ----------
    args : argparse.Namespace
        Its parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input (exit 2).

    """
    from sorter_sim.runtime.scene import apply_overrides, load_scene, run_scene

    scene = load_scene(args.scene)
    if args.overrides:
        scene = apply_overrides(scene, args.overrides)
    _, summary = run_scene(scene)
    if args.json:
        print(json.dumps(_json_safe(summary), sort_keys=True))
        return 0 if summary["success"] else 1
    p, b, d = scene["parcel"], scene["belt"], scene["diverter"]
    print(
        f"scene: {args.scene}  parcel {p['A']} x {p['B']} m, {p['m']} kg, phi0 {p['phi0_deg']} "
        "deg; "
        f"belt {b['v']} m/s, width {b['s']} m; alpha {d['alpha_deg']} deg; b = "
        f"{scene['zones']['b']} m"
    )
    print(f"  t_scrap        {_fmt(summary['t_scrap'], ' s')}")
    print(f"  x_scrap (x_o)  {_fmt(summary['x_scrap'], ' m')}")
    print(f"  phi at scrap   {_fmt(summary['phi_scrap_deg'], ' deg', 4)}")
    print(f"  capacity       {_fmt(summary['capacity_pcs_h'], ' pcs/h', 5)}")
    st = summary["stages"]
    print(
        f"  stages start   E1 {_fmt(st['E1'], ' s', 5)}, E2 {_fmt(st['E2'], ' s', 5)}, "
        f"E3 {_fmt(st['E3'], ' s', 5)}"
    )
    print(
        f"  solver         {summary['method']}: {summary['message']}; {summary['n_steps']} steps, "
        f"{summary['n_rhs']} rhs, {summary['n_events']} events, {summary['wall_s'] * 1e3:.2f} ms"
    )
    print(f"  reductions     {', '.join(summary['reductions']) or 'none'}")
    return 0 if summary["success"] else 1


def chosen_verb(argv: list[str], verbs: dict) -> str | None:
    """
    Return the verb ``argv`` names (its first word that is not an option), or None.

    Parameters
    ----------
    argv : list of str
        The arguments.
    verbs : dict
        verb -> (module, help).

    Returns
    -------
    str or None
        The verb, when it is one of ``verbs``.

    """
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in verbs else None


def build_parser(
    verbs: dict | None = None, argv: list[str] | None = None
) -> argparse.ArgumentParser:
    """
    Return the parser of the ``sorter`` command.

    With ``argv``, only the module of the verb it names is imported, for its arguments:
    the others' sub-parsers carry their one-line help. A verb whose module is missing from
    an installation does not break the others: it is refused when chosen.

    Parameters
    ----------
    verbs : dict, optional
        verb -> (module, help); default: this package's.
    argv : list of str, optional
        The arguments the parser is for: only the verb they name gets its arguments
        (default: every verb's module imported, every verb complete).

    Returns
    -------
    argparse.ArgumentParser
        The parser, one sub-parser per verb.

    """
    verbs = verbs or VERBS
    chosen = chosen_verb(argv, verbs) if argv is not None else None
    parser = _Parser(
        prog="sorter", description="Parcel sorter cell: model, studies and the running cell."
    )
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    for verb, (module, help_text) in verbs.items():
        p = sub.add_parser(verb, help=help_text, description=help_text)
        if argv is not None and verb != chosen:
            continue
        try:
            mod = importlib.import_module(module) if module != __name__ else sys.modules[__name__]
        except ImportError as exc:
            p.set_defaults(_verb_main=lambda _args, exc=exc: f"not installed here ({exc})")
            continue
        mod.add_arguments(p)
        p.set_defaults(_verb_main=mod.run)
    return parser


def main(argv: list[str] | None = None, verbs: dict | None = None) -> int:
    """
    Parse ``argv``, run the verb, turn its result into an exit code.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: the process's).
    verbs : dict, optional
        The verbs (default: this package's).

    Returns
    -------
    int
        The exit code: 0 done, 1 a run that failed, 2 a refused input.

    """
    apply_ros_env_defaults()
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        if chosen_verb(argv, verbs or VERBS):
            from sorter_sim.model.core.cache import check_kernel_cache

            check_kernel_cache()  # stale kernels dropped before any verb's module loads
        parser = build_parser(verbs, argv)  # imports the chosen verb's module
    except KeyboardInterrupt:  # Ctrl-C while the modules load: a clean stop
        return 130
    args = parser.parse_args(argv)
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        set_compile_quiet(True)  # the compile progress lines too
    if not getattr(args, "_verb_main", None):
        parser.print_help()
        return 2
    try:
        rc = args._verb_main(args)
    except ValueError as exc:  # SceneError is one
        print(f"sorter {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # the reader went away (e.g. `| head`); nothing left to say
        sys.stderr.close()
        return 0
    if isinstance(rc, str):
        print(f"sorter {args.verb}: error: {rc}", file=sys.stderr)
        return 2
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
