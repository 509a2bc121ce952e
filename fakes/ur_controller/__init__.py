"""A Universal Robots e-Series controller emulated at protocol level (RTDE 30004, dashboard 29999, script
ports 30002/30003) for the real ``ur_rtde`` clients. Parent-side handle: ``fakes.ur_controller_emulator``."""
