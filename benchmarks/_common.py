"""What the benchmark scripts share: the machine a measurement was made on.

The scripts import it as ``_common`` (a script's own folder is first on ``sys.path``); it imports
nothing of ``gimbal_lab``, so that a script comparing two trees can name the machine without
importing either. The package's own record of a machine is ``gimbal_lab.studies.report.machine``.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else what the platform module says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def machine() -> str:
    """One line: CPU model, core count, system and kernel release."""
    return f"{cpu_model()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"
