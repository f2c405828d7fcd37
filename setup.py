import os
import subprocess
import sys
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

try:  # setuptools >= 70.1; a colcon build with an older one (Ubuntu 24.04's) makes no wheel
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:
    bdist_wheel = None

package_name = 'sorter_cell'
HERE = Path(__file__).resolve().parent
SHIPPED_KERNELS = Path('sorter_sim', 'model', 'core', 'shipped_kernels')


class BuildPyWithKernels(build_py):
    """
    build_py that, for a wheel, ships the core's kernels compiled for any x86-64 CPU.

    Without them a user's first run compiles the model for minutes; with them it loads
    what it needs (sorter_sim/model/portable_kernels.py says how, and why portable).
    SORTER_KERNELS=none builds without them; SORTER_KERNELS=required fails the build when
    they cannot be compiled (otherwise the wheel is made without them, and says so);
    SORTER_KERNELS_FROM=<a checkout with these sources> compiles there, reusing that
    tree's cache (the test suite's).
    """

    ship_kernels = False

    def run(self):
        super().run()
        if not self.ship_kernels or os.environ.get('SORTER_KERNELS', '') == 'none':
            return
        root = Path(os.environ.get('SORTER_KERNELS_FROM') or HERE).resolve()
        dest = Path(self.build_lib).resolve() / SHIPPED_KERNELS
        command = [sys.executable, '-m', 'sorter_sim.model.portable_kernels', str(dest)]
        command += ['--from', str(root), '--sources', str(HERE / SHIPPED_KERNELS.parent)]
        # ahead of what is there: an isolated build (pip) finds its build environment
        # through PYTHONPATH
        path = os.pathsep.join(filter(None, [str(root), os.environ.get('PYTHONPATH')]))
        env = dict(os.environ, PYTHONPATH=path)
        done = subprocess.run(command, cwd=root, env=env, check=False)
        if done.returncode and os.environ.get('SORTER_KERNELS') == 'required':
            raise SystemExit(f'the portable kernels could not be compiled ({done.returncode})')
        if done.returncode:
            print(
                'warning: the portable kernels could not be compiled; the wheel has none '
                'and compiles them on first use (SORTER_KERNELS=required makes this an error)',
                file=sys.stderr,
            )


COMMANDS = {'build_py': BuildPyWithKernels}
if bdist_wheel is not None:

    class BdistWheelWithKernels(bdist_wheel):
        """bdist_wheel whose build ships the portable kernels (a release's wheel)."""

        def run(self):
            self.get_finalized_command('build_py').ship_kernels = True
            super().run()

    COMMANDS['bdist_wheel'] = BdistWheelWithKernels


# config/ and the folders of shipped scenes, scenarios and sweeps in it
CONFIG_DIRS = ['', 'scenes/', 'scenarios/', 'sweeps/']

setup(
    name=package_name,
    version='0.1.0',
    # config/ is also package data, sorter_cell.config: a wheel installed with pip finds
    # its parameter files, scenes and scenarios with importlib.resources, no environment
    # variable needed (sorter_ros.env.find_config_dir); share/ serves colcon/ament installs
    packages=find_packages(exclude=['test', 'test.*', 'benchmarks', 'examples'])
    + ['sorter_cell.config'],
    package_dir={'sorter_cell.config': 'config'},
    package_data={'sorter_cell.config': [f'{d}*.yaml' for d in CONFIG_DIRS]},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ]
    + [(f'share/{package_name}/config/{d}', glob(f'config/{d}*.yaml')) for d in CONFIG_DIRS],
    python_requires='>=3.11',
    install_requires=[
        'setuptools',
        'numpy>=2.0',
        'scipy>=1.13',
        'numba>=0.60',
        'PyYAML>=6.0',
        'matplotlib>=3.8',
        # sorter sweep: Dask runs a study on a cluster given --scheduler (and can
        # stand in for the local process pool); no home-made job distribution
        'dask[distributed]>=2024.1',
        'distributed>=2024.1',  # imported by name (dask[distributed] brings it)
        # sorter sweep: results written as Parquet when the output ends in .parquet
        'pyarrow>=14.0',
        # sorter sweep / sorter paper: the progress bar over the points of a study
        'tqdm>=4.66',
        # the live view: a Foxglove WebSocket server with Foxglove's own schemas
        # (sorter_sim/frontends/live_view.py), no ROS bridge needed
        'foxglove-sdk>=0.30',
        # recordings: MCAP files in the ros2 profile (sorter_ros/recording.py); the ROS 2
        # support package decodes them in sorter replay from the definitions inside;
        # 1.6: Writer.flush(), which closes a chunk on time (sorter_ros/recording_writer.py)
        'mcap>=1.6',
        'mcap-ros2-support>=0.5',
        # sorter recover and sorter replay inflate a chunk as a stream, bounded, rather
        # than mcap's whole-chunk decompression (a 33 kB chunk can state 1 GiB)
        'lz4>=4.0',
        'zstandard>=0.22',
        # a Foxglove client (python -m sorter_cell.live_snapshot, the live-view test):
        # WebSocket, and protobuf to decode the schemas the server advertises
        'websockets>=13',
        'protobuf>=4.25',
        # the fieldbus I/O image: Modbus TCP (server and the soft PLC's client) and OPC UA
        # (server and client), both the reference Python stacks of their protocol
        'pymodbus>=3.16,<4',
        'asyncua>=1.1',
        # S7 (ISO-on-TCP): python-snap7's server (pure Python) serves the image as data
        # blocks, its client is the soft PLC's; pinned because the cell's server replaces
        # its read and write handlers (sorter_sim/frontends/s7_server.py)
        'python-snap7==3.3.0',
        'ros-jazzy-rclpy[fastrtps]>=7.1',
        'ros-jazzy-common-interfaces>=5.3',
        # imported by name, so declared by name (rclpy brings both today): the message
        # definitions' parser of recordings, and the ament index (sorter_ros/env.py)
        'ros-rosidl-adapter>=4.6',
        'ros-ament-index-python>=1.8',
    ],
    extras_require={
        # the pytest a user's own tests of the fixtures run with: the versions the suite
        # runs, pinned as in 'test' (`pip install sorter_cell[pytest]`); the plugin itself
        # needs pytest 8
        'pytest': ['pytest>=8,<9.2', 'pytest-xdist>=3.5'],
        # pytest-xdist: the suite runs in a worker process, so that a test ended by its
        # time limit (test/suite_timeout.py) is an ordinary failure and the suite goes on
        # import-linter: the layer contracts in setup.cfg (test/test_layers.py);
        # ruff (flake8's checks) and ament-lint-pep257: lint as tests (test/test_lint.py);
        # hypothesis: the property-based fuzz tests of every input (test/test_fuzz.py)
        'test': [
            # below 9.2: its structured node ids drop the group suffix that xdist's
            # --dist loadgroup reads, and xdist_group marks stop grouping without a word
            # (pytest-xdist#1386); test/test_suite_timeout.py checks the grouping
            'pytest>=8,<9.2',
            'pytest-xdist>=3.5',
            'import-linter>=2.1',
            'ruff>=0.6',
            'ament-lint-pep257>=0.14',
            'hypothesis>=6.100',
            # independent clients in the suite: a Modbus TCP stack the cell does not use,
            # an independent rosbag2 reader with its own type store, and X.509 certificates
            # for the OPC UA identity tests
            'pyModbusTCP>=0.3',
            # the installed-package test builds the wheel and sdist as a user would
            # (python -m build, without network: setuptools with bdist_wheel built in)
            'build>=1.2',
            'setuptools>=70.1',
            'rosbags>=0.11',
            'cryptography>=42',
        ],
    },
    # the parameter files are handed to rcl by path: they must be files on disk
    zip_safe=False,
    cmdclass=COMMANDS,
    maintainer='sorter_cell maintainers',
    maintainer_email='sorter-cell@example.com',
    description=(
        'Emulated parcel sorter cell: belt conveyor with a pop-up '
        'torsional-disk diverter, simulation and controller nodes.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sorter = sorter_cell.cli:main',
            'sim_node = sorter_sim.executable:main',
            'controller_node = sorter_control.executable:main',
            'line_node = sorter_sim.executable:main_line',
            'wcs_node = sorter_control.executable:main_wcs',
        ],
        # the fixtures sorter_cell and sorter_controller in any project with this installed
        'pytest11': ['sorter_cell = sorter_cell.testing.plugin'],
    },
)
