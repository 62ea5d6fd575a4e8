"""Open a notebook in JupyterLab in headless chromium, run it, optionally press the microphone widget's Record /
Stop with a fake microphone playing a WAV, and save screenshots: what a reader sees, checked by a person.

    PYTHONPATH=$PWD .venv/bin/python tools/lab_screenshot.py 02a_phonetic_front_end --out runs/screenshots \\
        --record notebooks/data/real/agent-pass.flac

Writes ``<out>/<notebook>.png`` (the first screen after Run All) and, with ``--record``, ``<out>/<notebook>
-microphone.png`` (the microphone panel's cell after a 3 s recording was animated). Needs chromium (``apt-get
install chromium``) and the notebooks extra (JupyterLab, anywidget). The server runs on a free local port with a
random token and is stopped at the end.
"""
from __future__ import annotations

import argparse
import os
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wav(path: Path, folder: Path) -> Path:
    """Chromium's fake capture reads WAV only: any audio file -> a 16 kHz WAV."""
    import soundfile as sf

    from dualtalker_lite.audio import load_audio

    out = folder / "fake_microphone.wav"
    sf.write(out, load_audio(path), 16000, subtype="PCM_16")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("notebook", help="name under notebooks/, without .ipynb")
    ap.add_argument("--out", default="runs/screenshots")
    ap.add_argument("--record", default=None, help="audio file the fake microphone plays; press Record/Stop")
    ap.add_argument("--timeout", type=float, default=240, help="seconds to wait for Run All")
    ap.add_argument("--show", action="append", default=[], metavar="TEXT",
                    help="also screenshot the page scrolled to the first cell holding TEXT (NAME-show1.png, ...)")
    args = ap.parse_args(argv)
    exe = os.environ.get("DTL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        sys.exit("error: no chromium: apt-get install chromium (or set DTL_CHROMIUM)")
    from playwright.sync_api import sync_playwright

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    port, token = _free_port(), secrets.token_hex(16)
    tmp = Path(tempfile.mkdtemp(prefix="lab_shot_"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JUPYTER_CONFIG_DIR": str(tmp / "config")}
    server = subprocess.Popen(
        [sys.executable, "-m", "jupyter", "lab", "--no-browser", f"--port={port}", "--ip=127.0.0.1",
         f"--IdentityProvider.token={token}", f"--ServerApp.root_dir={ROOT / 'notebooks'}",
         "--LabApp.news_url=", "--allow-root"],
        env=env, stdout=subprocess.DEVNULL, stderr=open(tmp / "lab.log", "w"))
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(120):
            if server.poll() is not None:
                sys.exit(f"error: jupyter lab exited (code {server.returncode}); its log: {tmp / 'lab.log'}")
            try:
                urllib.request.urlopen(f"{base}/api?token={token}", timeout=2)
                break
            except OSError:
                time.sleep(1)
        flags = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
        if args.record:
            flags += ["--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
                      f"--use-file-for-fake-audio-capture={_wav(Path(args.record), tmp)}"]
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=exe, args=flags)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.goto(f"{base}/lab/tree/{args.notebook}.ipynb?token={token}")
            page.wait_for_selector(".jp-Notebook .jp-Cell", timeout=120000)
            page.wait_for_function("() => document.querySelector('.jp-Notebook-ExecutionIndicator, "
                                   "#jp-main-statusbar')", timeout=60000)
            time.sleep(3)                                    # the kernel starts
            page.locator(".lm-MenuBar-itemLabel", has_text="Run").first.click(timeout=30000)
            page.locator(".lm-Menu-itemLabel", has_text="Run All Cells").first.click(timeout=30000)
            t0 = time.time()
            while time.time() - t0 < args.timeout:           # every code cell numbered, none pending ([*])
                left = page.evaluate("() => Array.from(document.querySelectorAll('.jp-CodeCell "
                                     ".jp-InputPrompt')).filter(e => !/\\[\\d+\\]/.test(e.textContent)).length")
                if left == 0:
                    break
                time.sleep(2)
            print(f"run all: {time.time() - t0:.0f} s", flush=True)
            page.screenshot(path=str(out / f"{args.notebook}.png"))
            for i, text in enumerate(args.show, 1):          # a section in the middle: scrolled to its cell
                for _ in range(3):  # again after cells above it finish their layout (they move it down)
                    page.locator(".jp-Cell", has_text=text).first.scroll_into_view_if_needed(timeout=30000)
                    time.sleep(1.5)
                page.screenshot(path=str(out / f"{args.notebook}-show{i}.png"))
            if args.record:
                button = page.locator("button.dtl-rec").first
                button.scroll_into_view_if_needed()
                button.click()
                page.wait_for_function("() => document.querySelector('.dtl-status').textContent"
                                       ".startsWith('recording')", timeout=30000)
                time.sleep(3)
                button.click()
                page.wait_for_function("() => Array.from(document.querySelectorAll('.widget-label'))"
                                       ".some(e => / of speech animated in |error:/.test(e.textContent))",
                                       timeout=120000)
                time.sleep(2)
                cell = page.locator(".jp-CodeCell", has=page.locator("button.dtl-rec")).first
                cell.scroll_into_view_if_needed()
                cell.screenshot(path=str(out / f"{args.notebook}-microphone.png"))
                print(page.evaluate("() => Array.from(document.querySelectorAll('.widget-label'))"
                                    ".map(e => e.textContent).join(' | ')"), flush=True)
            browser.close()
    finally:
        server.terminate()
        server.wait(30)
    print(f"wrote {out}/{args.notebook}*.png")


if __name__ == "__main__":
    main()
