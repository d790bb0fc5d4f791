"""Plain buffers for the compiled core, without numpy (issue 29: the agent process does not load numpy).

The core's entry points take any C-contiguous buffer of the right item type and count (float64 ``d``, bool ``?``
or ``B``, int64 ``q``), so an agent holds its mission's constants and its state in ``array.array`` and shaped
``memoryview`` objects. numpy arrays are buffers too: the reference, the tools and the tests hand the core numpy
arrays as before, and read these buffers back with ``numpy.asarray`` (no copy, the shape kept).
"""

from __future__ import annotations

from array import array
from itertools import repeat

_ITEM = {"d": 8, "q": 8, "?": 1}


def f64(values) -> array | memoryview:
    """The numbers of ``values`` as a flat float64 buffer, rows in order: a flat or nested (rows of numbers)
    sequence, or a numpy array of any shape (copied as float64, C order). No numbers: an empty view that still
    points into memory (an empty array holds a null pointer, which the core is never handed)."""
    if type(values) is array and values.typecode == "d" and len(values):
        return values
    if hasattr(values, "dtype"):   # a numpy array (numpy is loaded, as it made it)
        out = array("d", values.astype("float64").ravel(order="C").tobytes())
    else:
        out = array("d")
        try:
            rows = iter(values)
        except TypeError:   # a bare number
            rows = iter((values,))
        for v in rows:
            try:
                out.append(v)   # a number (numpy's scalars too: array takes anything with __float__)
            except TypeError:
                out.extend(map(float, v))   # a row
    return out if len(out) else memoryview(array("d", (0.0,)))[:0]


def filled(typecode: str, shape: tuple[int, ...], value=0) -> memoryview:
    """A writable C-contiguous buffer of ``shape`` (typecode "d", "q" or "?"), every item ``value``. A buffer of no
    items still points into memory of its own (the core is never handed a null pointer)."""
    count = 1
    for k in shape:
        count *= k
    code = "b" if typecode == "?" else typecode   # array has no bool: bytes of 0 / 1, viewed as "?"
    store = array(code, repeat(int(value) if code != "d" else float(value), max(count, 1)))
    view = memoryview(store).cast("B")[:count * _ITEM[typecode]]
    return view.cast(typecode, shape) if count else view.cast(typecode)

