"""numpy bound on first use, for the modules an agent process imports (issue 29: the agent does not load numpy).

The agent runs its frames in the compiled core, with its state in plain buffers (vsfleet.agentcore); numpy is for
the readable reference, the tools and the tests. The modules on the agent's import path still hold that reference
beside the names the agent needs, so each binds ``np = lazy_numpy(globals())``: a stand-in that imports numpy the
first time one of its attributes is read, and then puts numpy itself in the module's namespace under the same
name, so every later ``np.x`` in that module is the plain global lookup it always was. A module that uses numpy
at import time (a constant array) must not: such a constant is built on first use instead.
tests/integration/test_agent_numpy_free.py runs an agent and checks that numpy was never loaded.
"""

from __future__ import annotations

import importlib


class LazyModule:
    """A module imported when one of its attributes is first read, then bound in ``namespace`` as ``alias``."""

    __slots__ = ("_name", "_namespace", "_alias")

    def __init__(self, name: str, namespace: dict, alias: str) -> None:
        self._name, self._namespace, self._alias = name, namespace, alias

    def __getattr__(self, attr: str):
        module = importlib.import_module(self._name)
        self._namespace[self._alias] = module   # later lookups in that module find the module itself
        return getattr(module, attr)

    def __repr__(self) -> str:
        return f"<{self._name}, imported on first use>"


def lazy_numpy(namespace: dict) -> LazyModule:
    """``np`` for a module's namespace (its ``globals()``): numpy, imported on first use."""
    return LazyModule("numpy", namespace, "np")
