"""A simulated kitchen cell: ``SimWorld`` holds the truth; fake drivers (FakeArm, FakeGripper, FakeCamera)
act on it; ``generate_scene`` makes random sink scenes; ``bop`` writes them as datasets; a Dynamixel
Protocol 2.0 emulator exercises the real gripper driver byte for byte."""

from kitchenbot.fakes.arm import ArmLog, FakeArm
from kitchenbot.fakes.camera import FakeCamera
from kitchenbot.fakes.collision import SimCollision
from kitchenbot.fakes.gripper import FakeGripper
from kitchenbot.fakes.scenes import generate_scene
from kitchenbot.fakes.world import Faults, SimClock, SimWorld

__all__ = [
    "ArmLog",
    "FakeArm",
    "FakeCamera",
    "FakeGripper",
    "Faults",
    "SimClock",
    "SimCollision",
    "SimWorld",
    "generate_scene",
]
