"""A trained policy on a vehicle: :class:`OnboardPolicy` (raw sensor readings in, commands
out), its export as a ``torch.export`` or ONNX program, the sensor-log format and the replay
of a log through the onboard loop (docs/onboard.md)."""

from dockingrl.onboard.export import export_onboard, export_onnx
from dockingrl.onboard.policy import OnboardPolicy, OnboardStep

__all__ = ["OnboardPolicy", "OnboardStep", "export_onboard", "export_onnx"]
