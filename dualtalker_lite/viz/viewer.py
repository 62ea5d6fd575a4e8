"""Interactive 3D views in the notebook: a live pythreejs viewer and a static, self-contained HTML fallback.

``MeshViewer`` needs a running kernel (JupyterLab 4 + ipywidgets 8 + pythreejs): drag to orbit, scroll to zoom,
and ``viewer.update(vertices)`` moves the mesh in place (only the position/normal arrays are re-sent).
Widgets do not survive notebook export, so committed notebooks use ``static_html``: trimesh's three.js viewer
with the mesh embedded, inside an ``<iframe srcdoc>`` (self-contained, about 0.75 MB, three.js included).
"""
from __future__ import annotations

import contextlib
import html
import warnings

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import Normalize, to_rgb

from ..export.render import CLAY, mesh_extent

__all__ = ["MeshViewer", "static_html", "vertex_normals", "vertex_colors"]


@contextlib.contextmanager
def _quiet_dtype_warnings():
    """pythreejs checks arrays against a float64 trait first and warns, then keeps float32/uint32 as given."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Given trait value dtype", category=UserWarning)
        yield


def _pythreejs():
    try:
        import pythreejs
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("MeshViewer needs pythreejs and ipywidgets: pip install 'dualtalker-lite[notebooks]' "
                          "(or use static_html(...) for a viewer without a kernel)") from err
    return pythreejs


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit normals: the area-weighted sum of the normals of the faces around each vertex."""
    tri = vertices[faces]  # (F, 3, 3)
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # (F, 3), length = 2 * area
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_n)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-20)


def vertex_colors(n_vertices: int, colors: np.ndarray | None = None, cmap: str = "viridis",
                  vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """(V, 3) RGB in [0, 1]: clay everywhere, or per-vertex scalars (V,) through ``cmap``."""
    if colors is None:
        return np.tile(np.asarray(to_rgb(CLAY)), (n_vertices, 1))
    values = np.asarray(colors, dtype=np.float64)
    if values.shape != (n_vertices,):
        raise ValueError(f"colors: expected shape ({n_vertices},), got {values.shape}")
    lo = np.nanmin(values) if vmin is None else vmin
    hi = np.nanmax(values) if vmax is None else vmax
    return colormaps[cmap](Normalize(lo, max(hi, lo + 1e-12), clip=True)(values))[:, :3]


class MeshViewer:
    """A live pythreejs view of one mesh; ``.widget`` is the ipywidget, ``.update(vertices)`` animates it.

    The orthographic camera looks at the face from the front (+z); drag to orbit, scroll to zoom.
    Tested in JupyterLab 4.6 + ipywidgets 8.1 + pythreejs 2.4.2 (headless Chromium).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None,
                 width: int = 400, height: int = 400, cmap: str = "viridis",
                 vmin: float | None = None, vmax: float | None = None, background: str = "white"):
        p3 = _pythreejs()
        vertices = np.asarray(vertices, dtype=np.float32)
        self.faces = np.asarray(faces, dtype=np.uint32)
        self.cmap, self.vmin, self.vmax = cmap, vmin, vmax
        with _quiet_dtype_warnings():
            self.position = p3.BufferAttribute(array=vertices, normalized=False)
            self.normal = p3.BufferAttribute(array=vertex_normals(vertices, self.faces).astype(np.float32),
                                             normalized=False)
            self.color = p3.BufferAttribute(
                array=vertex_colors(len(vertices), colors, cmap, vmin, vmax).astype(np.float32), normalized=False)
            index = p3.BufferAttribute(array=self.faces.ravel(), normalized=False)
        self.geometry = p3.BufferGeometry(
            index=index, attributes={"position": self.position, "normal": self.normal, "color": self.color})
        material = p3.MeshLambertMaterial(color="white", vertexColors="VertexColors", side="DoubleSide")
        self.mesh = p3.Mesh(geometry=self.geometry, material=material)

        centre, radius = mesh_extent(vertices, margin=0.25)  # head room: later frames may open the mouth wider
        aspect = width / height
        eye = centre + np.array([0.0, 0.0, 4 * radius])
        # A head light rides with the camera, so the face stays lit while orbiting. (pythreejs 2.4 under
        # ipywidgets 8 logs "Error setting state: t.on is not a function" in the browser console for any
        # directional light, from its shadow sub-model; the rendering is not affected.)
        head_light = p3.DirectionalLight(color="white", intensity=0.65, position=(-1.0, 1.5, 3.0))
        self.camera = p3.OrthographicCamera(left=-radius * aspect, right=radius * aspect, top=radius,
                                            bottom=-radius, near=radius * 0.01, far=radius * 20, position=tuple(eye),
                                            children=[head_light])
        scene = p3.Scene(children=[self.mesh, self.camera, p3.AmbientLight(color="white", intensity=0.4)],
                         background=background)
        self.controls = p3.OrbitControls(controlling=self.camera, target=tuple(centre))
        self.widget = p3.Renderer(camera=self.camera, scene=scene, controls=[self.controls],
                                  width=width, height=height, antialias=True)

    def update(self, vertices: np.ndarray, colors: np.ndarray | None = None) -> None:
        """New (V, 3) positions (and optionally per-vertex values) for the same topology."""
        vertices = np.asarray(vertices, dtype=np.float32)
        if vertices.shape != self.position.array.shape:
            raise ValueError(f"vertices: expected shape {self.position.array.shape}, got {vertices.shape}")
        with _quiet_dtype_warnings():
            self.position.array = vertices  # traitlets sync only the changed arrays to the browser
            self.normal.array = vertex_normals(vertices, self.faces).astype(np.float32)
            if colors is not None:
                self.color.array = vertex_colors(len(vertices), colors, self.cmap, self.vmin, self.vmax).astype(
                    np.float32)

    def player(self, frames: np.ndarray, fps: float = 30, colors: np.ndarray | None = None):
        """The viewer under a play button and frame slider driving ``update`` through a (T, V, 3) clip;
        ``colors`` (T, V): per-frame vertex values (e.g. an attention map over time), through the viewer's cmap."""
        import ipywidgets as widgets

        frames = np.asarray(frames, dtype=np.float32)
        if colors is not None:
            colors = np.asarray(colors, dtype=np.float64)
            if colors.shape != frames.shape[:2]:
                raise ValueError(f"colors: expected shape {frames.shape[:2]} (frames, vertices), got {colors.shape}")
        play = widgets.Play(value=0, min=0, max=len(frames) - 1, interval=int(1000 / fps), description="play")
        slider = widgets.IntSlider(value=0, min=0, max=len(frames) - 1, description="frame")
        widgets.jslink((play, "value"), (slider, "value"))

        def show(change):
            k = change["new"]
            self.update(frames[k], None if colors is None else colors[k])

        slider.observe(show, names="value")
        return widgets.VBox([widgets.HBox([play, slider]), self.widget])

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)


def static_html(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None, height: int = 400,
                cmap: str = "viridis", vmin: float | None = None, vmax: float | None = None):
    """An ``IPython.display.HTML`` three.js viewer (trimesh's) that needs no kernel: survives notebook export."""
    import trimesh
    from IPython.display import HTML
    from trimesh.viewer.notebook import scene_to_html

    rgb = vertex_colors(len(vertices), colors, cmap, vmin, vmax)
    rgba = np.concatenate([np.round(rgb * 255), np.full((len(rgb), 1), 255)], axis=1).astype(np.uint8)
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), vertex_colors=rgba,
                           process=False)
    page = scene_to_html(trimesh.Scene(mesh))
    return HTML(f'<div><iframe srcdoc="{html.escape(page, quote=True)}" width="100%" height="{int(height)}px" '
                f'style="border:none;"></iframe></div>')
