"""
ROS environment defaults and config lookup shared by the entry points.

This module imports nothing from ROS at module level, so the ROS-free parts of
the project (and their tests) can use it freely.

Network: left alone, Fast DDS announces every participant by multicast on every
network interface, so a simulated cell started on a laptop in an office or lab
network talks to (and is disturbed by) any other ROS 2 graph on the same
subnet. The entry points therefore call :func:`apply_ros_env_defaults` before
``rclpy.init()``, which keeps discovery on this host unless the user chose
otherwise:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is the default set here; a value
  already in the environment always wins.
* To reach nodes on other machines, set ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``
  (or ``SYSTEM_DEFAULT`` for the middleware's own default), and pick a
  ``ROS_DOMAIN_ID`` (0-232, shared by all nodes that should see each other)
  to keep separate graphs apart.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

PACKAGE_NAME = 'sorter_cell'

DISCOVERY_RANGE_VAR = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
DEFAULT_DISCOVERY_RANGE = 'LOCALHOST'

# config/ of a checkout (or an editable install): the repository root is the
# parent of this package.
SOURCE_CONFIG_DIR = Path(__file__).resolve().parents[1] / 'config'
# the same files as package data of an installed wheel (setup.py maps config/ there)
CONFIG_PACKAGE = 'sorter_cell.config'


def apply_ros_env_defaults() -> None:
    """
    Restrict DDS discovery to this host unless the user set a range.

    Call before ``rclpy.init()``; the setting is read when the context starts.
    A variable set but empty counts as unset: rmw would read an empty range as its
    own default (discovery on every interface), which nobody chooses by leaving it empty.
    """
    if not os.environ.get(DISCOVERY_RANGE_VAR, '').strip():
        os.environ[DISCOVERY_RANGE_VAR] = DEFAULT_DISCOVERY_RANGE


def _packaged_config_dir() -> Path | None:
    """Return the config folder installed as package data, if this is an installed package."""
    from importlib.util import find_spec

    try:
        spec = find_spec(CONFIG_PACKAGE)
    except ModuleNotFoundError:
        return None
    # a folder of data files (no __init__.py): a namespace portion, found where the wheel
    # put it; the parameter files are handed to rcl by path, so it must be a real folder
    for folder in (spec.submodule_search_locations or []) if spec else []:
        if Path(folder).is_dir():
            return Path(folder)
    return None


def _ament_config_dir() -> Path | None:
    """Return ``share/sorter_cell/config`` of a colcon/ament install, if the index knows it."""
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(PACKAGE_NAME)) / 'config'
    except (LookupError, OSError, ValueError):
        # PackageNotFoundError is a LookupError; OSError: no AMENT_PREFIX_PATH.
        return None


def find_config_dir() -> Path:
    """
    Return the directory of ``cell.yaml``, ``controller.yaml``, ``scenes/`` and ``scenarios/``.

    In this order: ``config/`` of a checkout next to this package (a checkout or an
    editable install), the package data of an installed wheel (``pip install``, found
    with ``importlib.resources``, no environment variable needed), then the share
    folder of a colcon/ament install (``share/sorter_cell/config``). The first that
    holds ``cell.yaml`` wins.

    Raises
    ------
    FileNotFoundError
        When none does, naming where it looked.

    """
    looked = [SOURCE_CONFIG_DIR]
    for candidate in (SOURCE_CONFIG_DIR, _packaged_config_dir(), _ament_config_dir()):
        if candidate is None:
            continue
        if candidate not in looked:
            looked.append(candidate)
        if (candidate / 'cell.yaml').is_file():
            return candidate
    raise FileNotFoundError(
        'sorter_cell config directory not found; looked in '
        f'{", ".join(map(str, looked))} and the package data {CONFIG_PACKAGE}. '
        'Reinstall the package (pip install sorter_cell), or run from a checkout.'
    )


SHIPPED_KINDS = ('scenes', 'scenarios', 'sweeps')


def shipped_file(kind: str, name: str) -> Path | None:
    """
    Return the shipped ``config/<kind>/<name>.yaml`` (a scene, scenario or sweep), if any.

    Lets a command take a shipped file by its name (``sorter scenario run
    stuck_divert_eye``) from any directory, installed or in a checkout.

    Parameters
    ----------
    kind : str
        One of ``SHIPPED_KINDS``.
    name : str
        The file's name, with or without ``.yaml``.

    Returns
    -------
    Path or None
        The file, or None when no shipped file has that name.

    """
    if kind not in SHIPPED_KINDS:
        raise ValueError(f'kind must be one of {", ".join(SHIPPED_KINDS)}, got {kind!r}')
    if not name or '/' in name or '\\' in name or name.startswith('.'):
        return None
    try:
        folder = find_config_dir() / kind
    except FileNotFoundError:
        return None
    path = folder / (name if name.endswith('.yaml') else f'{name}.yaml')
    return path if path.is_file() else None


def shipped_names(kind: str) -> list[str]:
    """Return the names of the shipped files of ``kind`` (for messages), sorted."""
    try:
        return sorted(p.stem for p in (find_config_dir() / kind).glob('*.yaml'))
    except FileNotFoundError:
        return []


class StopSignals:
    """
    SIGINT and SIGTERM as a request for a clean stop.

    The first signal only sets the request: the spin loop sees it within a tenth
    of a second, lets the node say its last words (the controller lowers the
    disks) and tears down. A second signal while the node still spins or speaks
    means the user is in a hurry (``hurry``): with ``hurry_raises`` (the demo's
    choice) it raises KeyboardInterrupt; without it (the nodes'), it only sets the
    flag, and the node skips what is left of its last words. Once the teardown has
    begun (``quiet``), signals change nothing: the teardown is short and bounded,
    and an exception there, or after it while the interpreter exits, would end the
    process by the signal rather than with exit code 0. A flag rather than an
    exception means no callback is ever cut in half: an exception raised inside
    the executor's spin can leave rclpy's wait set half torn down, and the
    teardown that follows then crashed (SIGSEGV, 1 double SIGINT of 100).
    """

    def __init__(self, hurry_raises: bool = True):
        import threading

        self.requested = threading.Event()
        self.hurry = False
        self.hurry_raises = hurry_raises
        self.quiet = False
        self._previous = {}

    def install(self) -> 'StopSignals':
        import signal

        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def restore(self) -> None:
        """Put back the handlers there were before ``install`` (for a caller that goes on)."""
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def _handler(self, signum, frame):
        if self.quiet:
            return
        if self.requested.is_set():
            self.hurry = True
            if self.hurry_raises:
                raise KeyboardInterrupt
            return
        self.requested.set()

    def is_set(self) -> bool:
        return self.requested.is_set()

    @contextlib.contextmanager
    def hurry_interrupts(self):
        """
        Turn the hurried stop's KeyboardInterrupt back into one where pybind11 changed it.

        Raised inside a callback the events executor called from C++, the second
        signal's KeyboardInterrupt comes out of pybind11 as a RuntimeError ("Unable to
        convert call argument"): after a hurry, that RuntimeError is the interrupt (130).
        """
        try:
            yield
        except RuntimeError:
            if self.hurry:
                raise KeyboardInterrupt from None
            raise


def _ignore_stop_signals() -> None:
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):  # not the main thread: nothing to change
            pass


def _rcl_arguments_refused(error: str) -> str:
    """
    Say in one line why rcl refused the command line, and what it takes instead.

    A params file rcl cannot open is named, with where this package's own are: the
    docs' ``--params-file config/cell.yaml`` is a checkout's path, and an installed
    package's copies are elsewhere.
    """
    import re

    detail = error.split(', at ')[0].removeprefix('failed to initialize rcl: ')
    detail = detail.replace('Error: error not set', '').strip().rstrip('.')
    unread = re.search(r"params file: '--params-file (.*?)'\. Error: Error opening YAML", detail)
    if unread is None:
        return (
            f'the ROS arguments are not valid: {detail}; a parameter is given as '
            "-p name:=value (an empty string quoted: -p name:=\"''\")"
        )
    try:
        shipped = f"this package's own are in {find_config_dir()}"
    except FileNotFoundError as exc:
        shipped = str(exc)
    return (
        f'the params file {unread.group(1)!r} cannot be opened (from {Path.cwd()}); '
        f'{shipped} (cell.yaml, controller.yaml)'
    )


def run_node(
    make_node, prog: str, config_errors: tuple = (ValueError,), args=None, stop=None
) -> None:
    """
    Run a node as every executable of this package does (ros2/demos talker style).

    Applies the discovery default, initialises rclpy, spins ``make_node()`` and
    tears down in ``finally``. A configuration error raised while the node is
    built (one of ``config_errors``) is printed as one line and exits with code 2.
    Once the node runs it never dies of a callback: see ``spin_surviving``.
    SIGINT and SIGTERM stop it cleanly, exit code 0 (see ``StopSignals``). An
    executable passes the ``stop`` it installed first thing (``start_node``), so that
    a signal while the node's modules still load is a clean stop too: a stop asked
    for before the node exists skips building it.

    Parameters
    ----------
    make_node : callable
        Builds the node (after rclpy is initialised); raises ValueError for a bad parameter.
    prog : str
        The executable's name, for messages.
    config_errors : tuple of type
        The exceptions that mean a bad configuration (one line, exit 2).
    args : list of str, optional
        The command line (default: the process's).
    stop : StopSignals, optional
        The executable's signal handlers, when it installed them first.

    """
    import sys

    import rclpy
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.signals import SignalHandlerOptions

    apply_ros_env_defaults()
    from sorter_ros.params_file import ros_arguments_problem

    # rcl reads a params file without bounds: each is checked first (size, keys, values)
    problem = ros_arguments_problem(sys.argv if args is None else args)
    if problem:
        print(f'{prog}: {problem}', file=sys.stderr)
        raise SystemExit(2)
    # rclpy's own handler would shut the context down at once, before the node could
    # say its last words over it
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rcl's RCLError: a command line rcl cannot parse
        print(f'{prog}: {_rcl_arguments_refused(str(exc))}', file=sys.stderr)
        raise SystemExit(2) from None
    node = None
    code = 0
    # handlers this call installs itself are its caller's to have back (a test, a program
    # that runs the node in-process and goes on); an executable's, from start_node, stay
    # ignored to the end of the process
    owned = stop is None
    try:
        if stop is None:
            stop = StopSignals(hurry_raises=False).install()
        try:
            node = None if stop.is_set() else make_node()
        except config_errors as exc:
            print(f'{prog}: {exc}', file=sys.stderr)
            code = 2
        except InvalidParameterTypeException as exc:
            # a parameter rclpy declares itself (use_sim_time:=x), refused by its type
            print(f'{prog}: {_type_refusal(exc)}', file=sys.stderr)
            code = 2
        else:
            if node is not None:
                spin_surviving(node, stop)
    except KeyboardInterrupt:
        pass
    finally:
        # the teardown is short and bounded: it finishes whatever signal comes now
        if stop is not None:
            stop.quiet = True
        _ignore_stop_signals()
        try:
            if node is not None:
                node.destroy_node()
        except KeyboardInterrupt:
            pass
        try:
            rclpy.try_shutdown()
        except KeyboardInterrupt:
            pass
        if owned and stop is not None:
            stop.restore()
    if code:
        sys.exit(code)


def _type_refusal(exc) -> str:
    """Say rclpy's refusal of a parameter's type as the nodes' own refusals read."""
    import re

    said = re.match(
        r"Trying to set parameter '([^']*)' to '(.*)' of type '(\w+)', expecting type '(\w+)'",
        str(exc),
        re.S,
    )
    if said is None:
        return str(exc)
    name, value, given, wanted = said.groups()
    wanted = {'BOOL': 'true or false', 'INTEGER': 'an integer', 'DOUBLE': 'a number'}.get(
        wanted, f'of type {wanted.lower()}'
    )
    return f'parameter {name!r} must be {wanted}, got {value!r} ({given.lower()})'


def start_node(node_module: str, args=None) -> None:
    """
    Console entry of an executable: catch the stop signals, then load and run its node.

    Loading numpy, numba, rclpy and the node's modules takes a few tenths of a
    second; with the handlers installed first, SIGINT or SIGTERM in that time is a
    clean stop (exit 0, no traceback) rather than a KeyboardInterrupt out of an
    import or death by SIGTERM. ``node_module`` names a module with
    ``main(args, stop)``; it is imported here, so this module stays light.

    Parameters
    ----------
    node_module : str
        The module whose ``main(args, stop)`` runs the node.
    args : list of str, optional
        The command line.

    """
    import importlib

    stop = StopSignals(hurry_raises=False).install()
    importlib.import_module(node_module).main(args, stop)


def spin_surviving(node, stop=None) -> int:
    """
    Spin ``node`` until its context shuts down or ``stop`` is set, surviving what callbacks raise.

    rclpy runs some callbacks of its own in the node's executor (the parameter
    services, the time source's /clock subscription); a malformed request there (a
    ParameterValue of an unknown type, a /clock stamp with negative seconds) raises
    out of ``spin_once`` and would end a plain ``rclpy.spin``. Here it is logged,
    counted in ``node.callback_errors`` (the nodes report it in their diagnostics)
    and the node spins on. Returns the count.

    A node whose class says ``executor_kind = 'events'`` is spun by rclpy's events executor
    (where there is one), the others by the single-threaded one.

    When ``stop`` (``StopSignals``, or any object with ``is_set()``) ends the loop, the node's
    ``last_words(executor)``, if it has one, runs before the executor goes: the
    context is still up, so it can still call a service.

    Parameters
    ----------
    node : rclpy.node.Node
        The node; one that owns other nodes lists itself and them in ``node.nodes``.
    stop : threading.Event
        Set to end the spin.

    Returns
    -------
    int
        The number of callback exceptions survived.

    """
    from rclpy.executors import ExternalShutdownException

    # the run loop's one executor picker (the events executor where rclpy has it)
    events = getattr(node, 'executor_kind', 'single') == 'events'
    executor = make_executor(node.context, events=events)
    # a node that owns others (a line and its stations) lists them all in ``nodes``
    for n in getattr(node, 'nodes', [node]):
        executor.add_node(n)
    node.callback_errors = 0
    try:
        while node.context.ok() and not (stop is not None and stop.is_set()):
            try:
                executor.spin_once(timeout_sec=0.1)
            except ExternalShutdownException:
                break
            except KeyboardInterrupt:
                raise
            except Exception as exc:
                # SIGINT/SIGTERM shut the context down between bytecodes, possibly in
                # the middle of a callback; what it raises then is part of shutting down
                if not node.context.ok():
                    break
                node.callback_errors += 1
                node.get_logger().error(
                    f'a callback raised {type(exc).__name__}: {exc}; ignored, the node goes on '
                    f'({node.callback_errors} so far)'
                )
        last_words = getattr(node, 'last_words', None)
        hurry = getattr(stop, 'hurry', False)
        if (
            stop is not None
            and stop.is_set()
            and not hurry
            and last_words is not None
            and node.context.ok()
        ):
            try:
                last_words(executor)
            except KeyboardInterrupt:
                raise
            except Exception as exc:
                node.get_logger().error(f'last words failed: {type(exc).__name__}: {exc}')
    finally:
        if stop is not None and hasattr(stop, 'quiet'):
            stop.quiet = True  # the teardown has begun
        executor.remove_node(node)
        executor.shutdown(timeout_sec=1.0)
    return node.callback_errors


def events_executor_class():
    """Return rclpy's events executor (C++, walks no wait set), or None where it is missing."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        return None
    return EventsExecutor


def make_executor(context, events: bool = True):
    """
    Return rclpy's events executor for ``context`` (or, without one, the single-threaded one).

    rclpy's events executor turns on ``faulthandler`` for the standard error it finds; a
    standard error without a file descriptor (pytest's ``capsys``, an embedding program)
    would refuse that and the executor with it: the process's own standard error is
    handed over instead, for as long as the executor is made.
    """
    from rclpy.executors import SingleThreadedExecutor

    events_class = events_executor_class() if events else None
    if events_class is None:
        return SingleThreadedExecutor(context=context)
    stderr = sys.stderr
    try:
        stderr.fileno()
    except (AttributeError, OSError, ValueError):
        sys.stderr = sys.__stderr__
    try:
        return events_class(context=context)
    finally:
        sys.stderr = stderr
