"""A per-point loss compiled into the loops (hybridfit.point_loss): the compiled copies' cache names."""

import os
import subprocess
import sys

import numba as nb

from hybridfit.point_loss import point_losses, specialise
from hybridfit.testing import toy_squared_point

PLAIN = nb.njit(toy_squared_point.py_func)
FAST = nb.njit(fastmath=True)(toy_squared_point.py_func)
FLAGS = nb.njit(fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})(toy_squared_point.py_func)


def _name(function) -> str:
    return specialise(point_losses, function).py_func.__qualname__


def test_one_function_compiled_with_other_options_is_cached_under_another_name():
    # numba's cache index does not tell floating-point options apart: one name would load the other's code
    names = {_name(PLAIN), _name(FAST), _name(FLAGS)}
    assert len(names) == 3


def test_a_cache_name_is_the_same_in_every_process():
    script = ("import numba as nb; from hybridfit.point_loss import point_losses, specialise; "
              "from hybridfit.testing import toy_squared_point as f; "
              "g = nb.njit(fastmath={'nsz', 'arcp', 'contract', 'afn', 'reassoc'})(f.py_func); "
              "print(specialise(point_losses, g).py_func.__qualname__)")
    names = {subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                            env={**os.environ, "PYTHONHASHSEED": str(seed)}).stdout.strip() for seed in (1, 2, 3)}
    assert names == {_name(FLAGS)}
