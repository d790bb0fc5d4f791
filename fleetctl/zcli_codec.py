"""msgpack codecs for the ``zenoh`` command of the zenoh-cli package.

zenoh-cli (``pip install zenoh-cli``) loads codecs from two entry-point groups,
``zenoh_cli.codecs.decoders`` and ``zenoh_cli.codecs.encoders``: it calls
``entry_point.load()`` and then, per sample, ``decoder(key, payload_bytes) -> str``
(the text it prints in place of ``{value}`` in ``--line``) or, for ``put``,
``encoder(key, value_text) -> bytes``. This project registers both as ``msgpack``
(pyproject.toml), so

    zenoh --mode client --connect tcp/ROUTER:7447 subscribe -k 'vs/demo/**' --decoder msgpack

prints every message as one line of JSON, and

    zenoh --mode client --connect tcp/ROUTER:7447 put -k vs/demo/fault/r2 \\
        --encoder msgpack -v '{"kind": "stop", "factor": 0.0, "duration": 0.0}'

injects a fault. The JSON is always valid: non-finite floats become the strings
"nan", "inf", "-inf"; binary fields become "base64:..."; non-string map keys
are turned into strings.
"""

from __future__ import annotations

import base64
import json
import math
from typing import Any

import msgpack


def jsonable(obj: Any) -> Any:
    """A JSON-serialisable copy of a decoded msgpack object (see the module doc)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else str(obj)
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return "base64:" + base64.b64encode(bytes(obj)).decode("ascii")
    if isinstance(obj, dict):
        return {k if isinstance(k, str) else json.dumps(jsonable(k)): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return repr(obj)  # msgpack ExtType and anything else exotic


def unpack_any(payload: bytes) -> Any:
    """Any msgpack value (not only maps); raises ValueError on bytes that are not one msgpack object."""
    try:
        return msgpack.unpackb(bytes(payload), raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types for bad bytes
        raise ValueError(f"not valid msgpack: {type(exc).__name__}: {exc}") from None


def msgpack_to_json(payload: bytes) -> str:
    """One line of JSON for a msgpack payload; ValueError if it is not msgpack."""
    return json.dumps(jsonable(unpack_any(payload)), separators=(",", ":"), allow_nan=False)


def decode_msgpack(key: Any, value: bytes) -> str:
    """zenoh-cli decoder: ``key`` (a zenoh KeyExpr or str, unused), payload bytes -> JSON line."""
    return msgpack_to_json(value)


def encode_msgpack(key: Any, value: str) -> bytes:
    """zenoh-cli encoder: a JSON text -> msgpack bytes (floats stay float64)."""
    try:
        obj = json.loads(value)
    except json.JSONDecodeError as exc:
        raise ValueError(f"value is not JSON: {exc}") from None
    return msgpack.packb(obj, use_bin_type=True)
