"""kitchenbot: a robot task executive that clears dishware from a kitchen sink.

The repository root is this package. Its parts, in the order data flows through them:
``drivers`` (Arm, Gripper, Camera) -> ``perception`` (views -> instances -> object poses) ->
``planning`` (grasps -> motions) -> ``tasks`` -> ``executive`` (state machine, CLI, daemon).
``calibration`` solves the hand-eye transform; ``fakes`` simulates one kitchen cell.
"""

__version__ = "0.1.0"
