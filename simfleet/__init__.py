"""The simulated fleet: N differential-drive robots with exact arc kinematics."""
