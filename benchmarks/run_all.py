"""Run the benchmark scripts in turn (what `make bench` does; a few minutes on 2 cores).

Left out because they take longer (run them by hand, see benchmarks/README.md): ``time_to_quality.py`` (about
2.5 CPU minutes per seed), ``collapse.py`` and ``long_audio.py --minutes 60`` / ``--cli``.
"""
import subprocess
import sys
from pathlib import Path

here = Path(__file__).resolve().parent
for script in ("data.py", "speed.py", "profile_step.py", "long_audio.py", "quality_dualtalker.py"):
    print(f"== {script}", flush=True)
    subprocess.run([sys.executable, str(here / script)], cwd=here, check=True)
