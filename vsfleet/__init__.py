"""vsfleet: virtual-structure formation control (Tan & Lewis, 1996).

The package holds pure math and the wire contract only: no zenoh, no clock,
no logging. Programs (agent/, simfleet/, tracker/) wrap it.
"""

__version__ = "0.1.0"
