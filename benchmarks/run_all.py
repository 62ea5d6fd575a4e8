"""Run every benchmark script in turn (what `make bench` does)."""
import subprocess
import sys
from pathlib import Path

here = Path(__file__).resolve().parent
for script in ("data.py", "speed.py", "quality_dualtalker.py"):
    print(f"== {script}", flush=True)
    subprocess.run([sys.executable, str(here / script)], cwd=here, check=True)
