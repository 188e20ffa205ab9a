"""Every figure of the lab; notebooks call one function per figure.

Plot functions take ``ax=None`` (or ``fig=None`` for multi-panel figures), return the
matplotlib figure or axes, never call ``plt.show()`` and change no global style at import.
Submodules group the figures by topic: ``camera``, ``kinematics``, ``scene``, ``detection``,
``control``, ``study``, ``occlusion``, ``scenario``, ``payoff``, ``light`` and ``sensor``.
"""

from . import camera, control, detection, kinematics, light, occlusion, payoff, scenario, scene, sensor, study
from ._common import interactive, save_figure

__all__ = ["camera", "control", "detection", "kinematics", "light", "occlusion", "payoff", "scenario", "scene", "sensor", "study", "save_figure", "interactive"]
