"""Program glue shared by every vsfleet process: zenoh flags and config, QoS,
process lifecycle, the embedded router and the localhost fleet launcher.

This is the I/O edge. The pure math lives in ``vsfleet``.
"""
