"""
setuptools' build backend, asking for what compiling the shipped kernels needs.

A wheel of sorter_cell carries the model's kernels compiled for any x86-64 CPU
(setup.py, ``BuildPyWithKernels``): building it runs the model, so an isolated wheel
build (``pip install <path>``, ``python -m build``) needs numba, NumPy, SciPy and PyYAML
in its build environment. Only the wheel needs them: an editable install, the sdist and
a wheel built with ``SORTER_KERNELS=none`` build with setuptools alone.
"""

import os

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403 - every hook is setuptools' own

KERNEL_BUILD_REQUIRES = ['numpy>=2.0', 'scipy>=1.13', 'numba>=0.60', 'PyYAML>=6.0']


def get_requires_for_build_wheel(config_settings=None):
    """Return setuptools' requirements for a wheel, and what compiling the kernels needs."""
    kernels = [] if os.environ.get('SORTER_KERNELS') == 'none' else KERNEL_BUILD_REQUIRES
    return _setuptools.get_requires_for_build_wheel(config_settings) + kernels
