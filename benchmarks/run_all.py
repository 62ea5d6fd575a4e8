"""Run the benchmark scripts in turn (what `make bench` does).

It took about 12 minutes of wall time on a busy 2-core machine (issue 34's report); not yet measured on a quiet one:
``python benchmarks/command_times.py --only make-bench`` does, into results/command_times.md.

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
