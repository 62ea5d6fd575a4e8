"""Visualisation helpers on a 0.1 m icosphere (stand-in for the face mesh) and a 'talking' deformed copy."""
import numpy as np
import pytest
import trimesh
from matplotlib import colormaps
from matplotlib.figure import Figure

from dualtalker_lite.viz import (
    MeshRenderer,
    animate_clip,
    plot_frames,
    plot_lip_distance,
    plot_vertex_map,
    plot_waveform_and_phonemes,
    render_frame_rgb,
)
from dualtalker_lite.export.video import ffmpeg_exe, stream_info
from dualtalker_lite.export.render import camera_rotation, visible_faces

FPS, SR = 30, 16000
WHITE = np.array([255, 255, 255])


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return mesh.vertices * 0.1, np.asarray(mesh.faces)  # (642, 3) metres, (1280, 3)


@pytest.fixture(scope="module")
def clip(sphere):
    """(90, V, 3): 3 s at 30 fps of a 'mouth' region on the front opening and closing twice a second."""
    v, _ = sphere
    mouth = np.exp(-(v[:, 0] ** 2 + (v[:, 1] + 0.05) ** 2) / 0.002) * (v[:, 2] > 0)  # (V,)
    opening = np.sin(2 * np.pi * 2 * np.arange(90) / FPS) ** 2  # (T,)
    return v[None] + opening[:, None, None] * mouth[None, :, None] * np.array([0.0, -0.02, 0.0])


@pytest.fixture(scope="module")
def wave():
    t = np.arange(3 * SR) / SR
    return (0.3 * np.sin(2 * np.pi * 220 * t) * np.sin(2 * np.pi * 2 * t) ** 2).astype(np.float32)


def _mesh_pixels(image):
    return np.any(image != WHITE, axis=-1)  # (H, W) True where something was drawn


def test_render_frame_rgb_shape_dtype_and_content(sphere):
    v, f = sphere
    image = render_frame_rgb(v, f, size=(320, 256), view="three_quarter")
    assert image.shape == (256, 320, 3) and image.dtype == np.uint8  # size is (width, height)
    assert 0.2 < _mesh_pixels(image).mean() < 0.9


def test_sphere_silhouette_area_matches_pi_r_squared(sphere):
    v, f = sphere
    # extent: half of the image's shorter side is 0.125 m -> 128 px / 0.125 m = 1024 px per metre
    image = render_frame_rgb(v, f, size=256, extent=((0.0, 0.0, 0.0), 0.125))
    r_px = 0.1 * 1024
    assert _mesh_pixels(image).sum() == pytest.approx(np.pi * r_px**2, rel=0.10)


def test_back_face_culling_draws_about_half_a_sphere(sphere):
    v, f = sphere
    for view in ("front", "side", "three_quarter"):
        assert visible_faces(v, f, view).mean() == pytest.approx(0.5, abs=0.05)
    renderer = MeshRenderer(64)
    renderer.render(v, f)
    assert renderer.n_drawn == pytest.approx(len(f) / 2, rel=0.1)


def test_camera_views_are_rotations():
    for view in ("front", "side", "three_quarter"):
        r = camera_rotation(view)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(camera_rotation("front"), np.eye(3), atol=1e-12)
    assert camera_rotation("side") @ [0, 0, 1] == pytest.approx([-1, 0, 0])  # profile: the nose points left


def test_per_vertex_colors_follow_the_colormap(sphere):
    v, f = sphere
    image = render_frame_rgb(v, f, size=128, colors=v[:, 0], cmap="viridis", shading=0.0)
    row = image[64]  # middle row: from the leftmost (min x) to the rightmost (max x) mesh pixel
    cols = np.flatnonzero(_mesh_pixels(image)[64])
    low, high = (np.asarray(colormaps["viridis"](q)[:3]) * 255 for q in (0.0, 1.0))
    assert np.abs(row[cols[0] + 2] - low).max() < 30
    assert np.abs(row[cols[-1] - 2] - high).max() < 30


def test_painter_draws_the_nearer_triangle_on_top():
    # Two overlapping triangles facing the camera; the far one (value 0) is listed last on purpose.
    v = np.array([[-1, -1, 0.5], [1, -1, 0.5], [0, 1, 0.5], [-1, -1, 0.0], [1, -1, 0.0], [0, 1, 0.0]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    image = render_frame_rgb(v, f, size=32, colors=np.array([1.0, 1, 1, 0, 0, 0]), shading=0.0)
    near = np.asarray(colormaps["viridis"](1.0)[:3]) * 255
    assert np.abs(image[16, 16] - near).max() < 2


def test_animate_clip_writes_h264_mp4_with_audio(tmp_path, clip, sphere, wave):
    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg")
    import imageio_ffmpeg

    anim = animate_clip(clip, sphere[1], wave, sample_rate=SR, fps=FPS, path=tmp_path / "clip.mp4", size=256)
    assert anim.path.exists() and anim.has_audio and anim.size == (256, 256)
    assert anim.path.stat().st_size < 300_000  # a 3 s clip stays small enough to commit
    frames = imageio_ffmpeg.read_frames(str(anim.path))
    meta = next(frames)
    assert meta["size"] == (256, 256)
    assert abs(sum(1 for _ in frames) - len(clip)) <= 1
    streams = stream_info(anim.path)
    assert "Video: h264" in streams and "yuv420p" in streams and "Audio: aac" in streams
    html = anim._repr_html_()
    assert html.startswith("<video controls") and "data:video/mp4;base64," in html


def test_animate_clip_side_by_side_without_audio(tmp_path, clip, sphere):
    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg")
    error = np.linalg.norm(clip[:6] - clip[0], axis=-1)  # (T, V)
    anim = animate_clip({"ground truth": clip[:6], "prediction": clip[:4]}, sphere[1], size=63,
                        colors={"prediction": error[:4]}, path=tmp_path / "pair.mp4")
    assert anim.size == (128, 64) and anim.n_frames == 6 and not anim.has_audio  # even sizes for yuv420p
    streams = stream_info(anim.path)
    assert "128x64" in streams and "Audio:" not in streams


@pytest.mark.parametrize("forced", [True, False])
def test_animate_clip_javascript_fallback(clip, sphere, wave, capsys, monkeypatch, forced):
    if not forced:  # no ffmpeg on the machine: the default use_ffmpeg=None falls back by itself
        monkeypatch.setattr("dualtalker_lite.viz.animate.ffmpeg_exe", lambda: None)
    anim = animate_clip(clip[:5], sphere[1], wave, size=64, use_ffmpeg=False if forced else None)
    assert anim.path is None and not anim.has_audio
    assert "silent JavaScript animation" in capsys.readouterr().out
    html = anim._repr_html_()
    assert "data:image/jpeg;base64" in html and html.count("frames[") >= 5


def test_mesh_viewer_update_changes_positions(sphere):
    pytest.importorskip("pythreejs")
    from dualtalker_lite.viz import MeshViewer

    v, f = sphere
    viewer = MeshViewer(v, f, colors=v[:, 1], width=200, height=150)
    assert viewer.widget.width == 200 and viewer.position.array.shape == v.shape
    before = viewer.position.array.copy()
    viewer.update(v * 1.1, colors=v[:, 0])
    np.testing.assert_allclose(viewer.position.array, v * 1.1, rtol=1e-6)
    assert not np.allclose(viewer.position.array, before)
    with pytest.raises(ValueError):
        viewer.update(v[:10])


def test_mesh_viewer_player_steps_through_frames_and_colours(sphere):
    pytest.importorskip("pythreejs")
    from dualtalker_lite.viz import MeshViewer

    v, f = sphere
    frames = np.stack([v * (1 + 0.1 * k) for k in range(4)])  # (4, V, 3)
    values = np.stack([v[:, 1] * (k + 1) for k in range(4)])   # (4, V): a map that changes over time
    viewer = MeshViewer(v, f, colors=values[0], vmin=float(values.min()), vmax=float(values.max()))
    box = viewer.player(frames, colors=values)
    slider = box.children[0].children[1]
    first_colours = viewer.color.array.copy()
    slider.value = 3
    np.testing.assert_allclose(viewer.position.array, frames[3], rtol=1e-6)
    assert not np.allclose(viewer.color.array, first_colours)  # the colours followed the frame
    with pytest.raises(ValueError, match="colors: expected shape"):
        viewer.player(frames, colors=values[:2])


def test_static_html_embeds_a_self_contained_viewer(sphere):
    from dualtalker_lite.viz import static_html

    page = static_html(*sphere).data
    assert page.startswith("<div><iframe srcdoc=") and "THREE" in page and "&quot;" in page  # srcdoc-escaped


def _assert_labelled(fig):
    assert isinstance(fig, Figure)
    assert fig.get_suptitle() or any(ax.get_title() for ax in fig.axes)
    assert any(ax.get_xlabel() and ax.get_ylabel() for ax in fig.axes)
    assert all("(" in ax.get_xlabel() for ax in fig.axes if ax.get_xlabel())  # units


def test_plots_return_titled_labelled_figures(clip, sphere, wave):
    f = sphere[1]
    phonemes = [["sil", 0.0, 0.3], ["HH", 0.3, 0.4], ["AH", 0.4, 0.6], ["sil", 0.6, 3.0]]
    times = np.arange(len(clip)) / FPS
    gap = np.ptp(clip[:, :, 1], axis=1) * 1e3  # (T,) mm, a stand-in for the lip distance
    error = np.linalg.norm(clip[30] - clip[0], axis=-1) * 1e3
    figs = [
        plot_frames(clip[::30], f, titles=["t=0 s", "t=1 s", "t=2 s"]),
        plot_frames(clip[:2], f, view="side", colors=np.stack([error, error])),
        plot_vertex_map(clip[30], f, error, "Vertex error", label="L2 error", vmin=0),
        plot_lip_distance(times, {"ground truth": gap, "prediction": gap * 0.9}, phonemes),
        plot_waveform_and_phonemes(wave, SR, phonemes),
    ]
    for fig in figs:
        _assert_labelled(fig)
    assert figs[3].axes[0].get_ylabel() == "lip distance (mm)"
    assert len(figs[2].axes) == 3  # two views and a colour bar
