"""The first step of an explicit run with numba's on-disk cache empty: two cores compile.

numba's front end holds the GIL, so a thread compiles nothing in parallel; a second process
does (:func:`fem_rmpm.runtime.numba_cache.compile_aside`).  On a machine of two or more
cores, before the first call of a step driver whose code is not in the cache:

* **one thread** (:func:`serial_driver_ready`): a helper process compiles the stress pass
  (its kernel for the run's basis and model path, about half of what the first step
  compiles) while this process compiles the map and the map back; the driver's compile
  then loads the stress pass from the cache;
* **two threads** (:func:`threaded_driver_ready`): the helper compiles the stress pass,
  then the two-thread driver (``advance_pair``, or ``advance_parallel`` with F-bar) into
  the cache; meanwhile this process compiles the serial driver as above and runs the first
  steps on it, with one thread, until the helper is done; the next driver call loads the
  threaded driver from the cache.  One and two threads give bitwise the same steps
  (``tests/test_threads.py``), so the run is the one of the threaded driver alone.

The helper compiles the same kernels for the same argument types as the driver's own
compile, so the same code; a helper that fails or is late only costs its compile here.
A helper still compiling when the process ends is waited for (:func:`_wait_helpers`): the
cache then holds every kernel of the run for the next one.  A run stopped by an interrupt
(Ctrl-C, SIGTERM) or an error stops its helpers at once (:func:`stop_helpers`): the
command's exit does not wait for a compile.
"""
from __future__ import annotations

import atexit

from numba import typeof, types

from fem_rmpm.materials import registry
from fem_rmpm.runtime.machine import usable_cores
from fem_rmpm.runtime.numba_cache import Helper, cached, compile_aside
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.kernels import advance as _advance
from fem_rmpm.schemes.explicit.kernels import stress as _stress
from fem_rmpm.schemes.explicit.kernels import transfer as _transfer

__all__ = ["serial_driver_ready", "threaded_driver_ready", "stop_helpers"]

#: The stress pass's kernel of :func:`.kernels.stress.stress_queue` for (gimp, block).
_QUEUES = {(False, False): "_QUEUE_Q4_POINTS", (False, True): "_QUEUE_Q4_BLOCK",
           (True, False): "_QUEUE_GIMP_POINTS", (True, True): "_QUEUE_GIMP_BLOCK"}
#: Helpers compiling a threaded driver, by driver: the run steps on the serial driver
#: until its helper is done.
_PENDING: dict = {}


def _stress_item(P, M, N, S, o) -> dict | None:
    """The :func:`compile_aside` item of the run's stress-pass kernel, None if cached."""
    queue = _QUEUES[(bool(o.gimp), bool(o.block))]
    sig = (types.literal(registry.version()), types.literal(int(o.model)),
           types.literal(bool(o.fbar)), typeof(P), typeof(M), typeof(K.top_of(N)),
           typeof(N.half), typeof(S), typeof(o), types.int64)
    if cached(getattr(_stress, queue), sig):
        return None
    return {"module": _stress.__name__, "name": queue, "sig": sig,
            "check": [registry.__name__, "version", registry.version()]}


def _compile_transfers(P, M, N, S, o) -> None:
    """The serial driver's map, map back and nodal velocities (for the run's basis), in
    this process."""
    gimp = types.literal(bool(o.gimp))
    tp, tm, tn, ts, to = typeof(P), typeof(M), typeof(N), typeof(S), typeof(o)
    K.map_to_nodes.compile((gimp, tp, tm, tn, ts, to))
    K.solve_and_move.compile((gimp, tp, tm, tn, ts, to))
    _transfer.nodal_velocity_half.compile((tm, typeof(K.top_of(N)), typeof(N.half),
                                           types.int64))


def _first_serial_compile(args: tuple, helper: Helper) -> None:
    """Compile the serial driver's transfers for its arguments ``args`` here while ``helper``
    compiles the stress pass (its first item); then wait for that item, so the driver's
    compile loads it."""
    P, M, N, S, o = args[:5]
    try:
        _compile_transfers(P, M, N, S, o)
    except Exception:        # noqa: BLE001 - the driver's own compile follows anyway
        pass
    helper.wait_items(1)


def serial_driver_ready(serial, args: tuple) -> None:
    """Before the first call of the serial driver ``serial`` with ``args`` (``P, M, N, S``
    and its step options first): if its code is not cached and two cores are there,
    compile the stress pass in a helper process while this one compiles the transfers
    (module docstring)."""
    try:
        if serial.signatures or usable_cores() < 2 or cached(serial,
                                                            tuple(typeof(a) for a in args)):
            return
        item = _stress_item(*args[:5])
    except Exception:        # noqa: BLE001 - numba internals moved: the driver compiles all
        return
    if item is not None:
        helper = compile_aside([item])
        _first_serial_compile(args, helper)
        helper.wait()


def threaded_driver_ready(kind: str, driver, args: tuple, key: tuple, serial,
                          serial_args: tuple) -> bool:
    """Whether the run steps on the threaded ``driver`` now (``kind``: ``"pair"`` or
    ``"parallel"``; ``args`` its arguments; ``key`` the arguments of
    :func:`.kernels.advance.step_drivers` that made it).  False while a helper compiles it
    into the cache (module docstring): the caller steps on ``serial`` with ``serial_args``
    (their step options with one thread), made ready here at its first call."""
    helper = _PENDING.get(driver)
    if helper is None:
        if driver.signatures or usable_cores() < 2:
            return True
        try:
            sig = tuple(typeof(a) for a in args)
            if cached(driver, sig):
                return True
            stress = _stress_item(*serial_args[:5])
        except Exception:    # noqa: BLE001 - numba internals moved: compile it here
            return True
        items = [] if stress is None else [stress]
        items.append({"module": _advance.__name__, "name": "step_drivers",
                      "factory": list(key), "index": 2 if kind == "pair" else 1, "sig": sig,
                      "check": [registry.__name__, "version", registry.version()]})
        helper = compile_aside(items)
        if helper.proc is None:
            return True
        _PENDING[driver] = helper
        if not serial.signatures and stress is not None:
            _first_serial_compile(serial_args, helper)
        return False
    state = helper.done()
    if state is None:
        return False
    del _PENDING[driver]
    return True


def stop_helpers() -> None:
    """Stop the helpers still compiling (a run stopped by an interrupt or an error); their
    locked saves leave no partial cache entry."""
    for helper in list(_PENDING.values()):
        helper.stop()
    _PENDING.clear()


@atexit.register
def _wait_helpers() -> None:
    """At the end of the process: wait for the helpers still compiling (module docstring)."""
    for helper in list(_PENDING.values()):
        helper.wait()
    _PENDING.clear()
