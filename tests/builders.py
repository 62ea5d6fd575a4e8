"""Small builders shared by the model test modules (imported as ``from builders import ...``: pytest puts this
folder on ``sys.path``, it has no ``__init__.py``)."""
import torch


def perturbed(model, scale=0.05, seed=0):
    """An untrained model has zero decoders (it outputs the template): give every weight some value."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=g) * scale)
    return model.eval()


def grid_faces(rows=4, cols=5):
    """A flat (rows x cols) grid, two triangles per square, consistently oriented: V = rows x cols = 20 vertices."""
    faces = []
    for i in range(rows - 1):
        for j in range(cols - 1):
            a, b, c, d = i * cols + j, i * cols + j + 1, (i + 1) * cols + j, (i + 1) * cols + j + 1
            faces += [(a, b, d), (a, d, c)]
    return torch.tensor(faces).numpy()


def fake_microphone_args(wav, loop: bool = False) -> list[str]:
    """Chromium's flags for the live-page tests: software WebGL, a fake microphone that plays ``wav`` (once unless
    ``loop``), microphone permission granted and autoplay allowed."""
    return ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
            f"--use-file-for-fake-audio-capture={wav}{'' if loop else '%noloop'}",
            "--autoplay-policy=no-user-gesture-required"]
