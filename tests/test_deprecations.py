"""Old names keep working for one release (issue 46): each warns with its new address and gives the same object;
CHANGELOG.md lists every one."""
from __future__ import annotations

import importlib
import re
import warnings
from pathlib import Path

import pytest

OLD_ADDRESSES = [  # (module, old name, new module, new name)
    *[("dualtalker_lite.utils", name, new, name) for name, new in (
        ("set_seed", "dualtalker_lite.seeding"), ("check_shape", "dualtalker_lite.checks"),
        ("load_npy", "dualtalker_lite.checks"), ("check_finite", "dualtalker_lite.checks"),
        ("NonFiniteError", "dualtalker_lite.checks"), ("runs_dir", "dualtalker_lite.files"),
        ("atomic_torch_save", "dualtalker_lite.files"), ("repo_root", "dualtalker_lite.files"),
        ("default_file_mode", "dualtalker_lite.files"), ("AtomicOutputDir", "dualtalker_lite.files"),
        ("atomic_write_text", "dualtalker_lite.files"), ("watch_parent", "dualtalker_lite.processes"))],
    *[("dualtalker_lite.viz.render", name, "dualtalker_lite.export.render", name)
      for name in ("draw_mesh", "render_frame_rgb", "MeshRenderer", "RasterRenderer", "VIEWS")],
    *[("dualtalker_lite.experiments", name, f"dualtalker_lite.{new}", name) for name, new in (
        ("_display_path", "experiments.command"), ("_unpad", "experiments.evaluation"), ("_git", "provenance"),
        ("_collapse_note", "experiments.report"), ("_compare", "experiments.report"), ("_fmt", "experiments.report"),
        ("_DATA", "experiments.runner"), ("_job", "experiments.runner"), ("_trimmed", "experiments.runner"),
        ("_worker_init", "experiments.runner"))],
    ("dualtalker_lite.experiments", "FRONT_ENDS", "dualtalker_lite.experiments.specs", "FRONT_END_NOTES"),
    ("dualtalker_lite.experiments.specs", "FRONT_ENDS", "dualtalker_lite.experiments.specs", "FRONT_END_NOTES"),
]


@pytest.mark.parametrize("module, old, new_module, new", OLD_ADDRESSES)
def test_an_old_address_warns_with_the_new_one_and_forwards(module, old, new_module, new):
    target = getattr(importlib.import_module(new_module), new)
    with pytest.warns(DeprecationWarning, match=rf"^{module}\.{old} is deprecated .*; use {new_module}\.{new}$"):
        got = getattr(importlib.import_module(module), old)
    assert got is target


def test_from_import_of_an_old_name_warns_and_an_unknown_name_still_fails():
    with pytest.warns(DeprecationWarning, match="use dualtalker_lite.export.render.draw_mesh"):
        from dualtalker_lite.viz.render import draw_mesh  # noqa: F401  (notebook 01's import before issue 46)
    import dualtalker_lite.utils as utils
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        utils.no_such_name


def test_the_package_itself_uses_no_old_address():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        import dualtalker_lite.experiments  # noqa: F401  (its __init__ re-exports the public names only)
        import dualtalker_lite.viz  # noqa: F401


def test_renamed_keywords_warn_and_forward(tmp_path):
    from dualtalker_lite import front_ends
    from dualtalker_lite.audio import LogMelExtractor

    logmel = LogMelExtractor()
    with pytest.warns(DeprecationWarning, match=r"front_ends\.settings\(extractor=\.\.\.\) is deprecated"):
        old = front_ends.settings("logmel", extractor=logmel)
    assert old == front_ends.settings("logmel", front_end=logmel)
    with pytest.raises(TypeError, match=r"got both extractor= \(deprecated\) and front_end="):
        front_ends.settings("logmel", logmel, extractor=logmel)


def test_the_checkpoint_names_of_the_front_end_functions_warn_and_forward():
    from dualtalker_lite import checkpoints, front_ends

    with pytest.warns(DeprecationWarning, match=r"use dualtalker_lite\.front_ends\.settings\(name, front_end\)$"):
        assert checkpoints.extractor_settings() == front_ends.settings()
    with pytest.warns(DeprecationWarning, match=r"use dualtalker_lite\.front_ends\.from_settings$"):
        assert checkpoints.extractor_from_settings(None).dim == front_ends.from_settings(None).dim


def test_the_dataset_takes_its_front_end_under_the_old_keyword_too():
    from dualtalker_lite.audio import LogMelExtractor
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.dataset import TalkingFaceDataset

    logmel = LogMelExtractor(fps=30)
    with pytest.warns(DeprecationWarning, match=r"TalkingFaceDataset\(extractor=\.\.\.\) is deprecated.*"
                                                r"use TalkingFaceDataset\(front_end=\.\.\.\)$"):
        data = TalkingFaceDataset(sample_path(), "val", extractor=logmel)
    assert data.front_end is logmel
    with pytest.warns(DeprecationWarning, match=r"use TalkingFaceDataset\.front_end$"):
        assert data.extractor is logmel


def test_the_changelog_lists_every_old_address():
    changelog = (Path(__file__).resolve().parents[1] / "CHANGELOG.md").read_text()
    for module, old, _, _ in OLD_ADDRESSES:
        assert module in changelog and re.search(rf"(?<!\w){re.escape(old)}(?!\w)", changelog), (module, old)
    for old in ("TalkingFaceDataset(extractor=", "PairDataset(extractor=", "front_ends.settings(extractor=",
                "TalkingFaceDataset.extractor", "PairDataset.extractor", "checkpoints.extractor_settings",
                "checkpoints.extractor_from_settings"):
        assert old in changelog, old
