# %% [markdown]
# # 13 · Spiral convolution on the face: SpiralConv3D and Mesh Attention (EmoFace, eqs. 1-3)
#
# EmoFace predicts two sets of vertex offsets per frame, one from an *emotion* branch and one from a *content*
# branch, and fuses them with **Mesh Attention**: a weight per vertex and per frame saying how much of the
# emotion branch to take. The weight comes out of **SpiralConv3D**, a convolution that works directly on the
# mesh: in space it reads a vertex's neighbours along a *spiral* (the centre, its ring of neighbours, the next
# ring, ...), and in time it reads the same vertex over the last $\delta$ frames. This notebook builds both from
# the face list of our template head, checks them against the package, and runs an (untrained) Mesh Attention
# on an emotional clip of the corpus.
#
# **We will cover**
#
# 1. The face as a graph: rings and $k$-disks (eq. 1).
# 2. Spirals: one fixed order per vertex (SpiralNet++), its starting point, length and dilation (Table 4).
# 3. Boundaries and the fallback: open the lip slit, and what happens where rings run out.
# 4. Time: the causal neighbourhood of eq. 2.
# 5. SpiralConv3D (eq. 3) built step by step from scratch and checked against `SpiralConv3D`; causality.
# 6. Relabelling the vertices: the spirals follow them.
# 7. Mesh Attention on a corpus clip: the attention map on the face.
# 8. The fitted map on the talking face, in 3D.
# 9. EmoFace's Table 4 (kernel size, dilation, duration) at tiny scale: the stored sweep.
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $V$ (mesh vertices), $T$ (frames), $B$ (batch) | `V`, `T`, `B` | int |
# | $i\text{-ring}(v)$, $k\text{-disk}(v)$ | `k_rings(faces, V, v, k)[i]` | list of ids |
# | spiral of $v$ (the ordered $k$-disk), length $L$ | `spirals[v]` | (V, L) int64 |
# | padded spiral slot | `~spiral_mask(spirals)` | (V, L) bool |
# | $\delta$ (time duration), $cnt_\delta$ | `delta`, `temporal_neighbourhood(x, delta)` | (B, T, δ, ...) |
# | $f(\cdot)$ (vertex features) | `x` | (B, T, V, C) |
# | $W$, $b$ of eq. 3 | `conv.weight`, `conv.bias` | (C_out, δ, L, C_in), (C_out,) |
# | $F_{e1}$, $F_{c1}$ (branch features) | `emotion_feat`, `content_feat` | (B, T, C) |
# | $F_{audio}$, $F_{vertices\text{-}emb}$ | `att.audio_feature(...)`, `att.vertex_embedding` | (B, T, C/16), (V, C/16) |
# | Temporal Mesh Attention Map | `a` | (B, T, V) in [0, 1] |
# | $\Delta M^e$, $\Delta M^c$, $\Delta M$ | `emotion_offsets`, `content_offsets`, `fused` | (B, T, V·3) |

# %%
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import display

from dualtalker_lite.audio import LogMelExtractor
from dualtalker_lite.blocks import MeshAttention, SpiralConv3D, k_rings, spiral_indices, spiral_mask
from dualtalker_lite.blocks.spiral import one_ring_order, spiral_ring_index, temporal_neighbourhood
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.face.mesh import build_template
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import MeshViewer, plot_frames, plot_spirals, plot_vertex_map

torch.set_num_threads(1)
gen = set_seed(0)
corpus = Corpus(sample_path())
mesh = build_template()  # the canonical head: the same faces as every speaker's template in the corpus
faces, V = corpus.faces, mesh.n_vertices
assert np.array_equal(faces, mesh.faces)
regions = corpus.regions

# %% [markdown]
# ## 1. The face as a graph: rings and $k$-disks
#
# Forget the 3-D positions for a moment: the faces list which vertices are joined by an edge. The $k$-ring of a
# vertex $v$ is everything exactly $k$ edges away, and the $k$-disk everything at most $k$ edges away:
#
# $$0\text{-ring}(v) = \{v\}, \qquad (k{+}1)\text{-ring}(v) = \mathcal{N}\big(k\text{-ring}(v)\big) \setminus k\text{-disk}(v),
# \qquad k\text{-disk}(v) = \textstyle\bigcup_{i=0,\dots,k} i\text{-ring}(v) \tag{1}$$
#
# where $\mathcal{N}(S)$ is every vertex joined by an edge to a vertex of $S$. `k_rings` is eq. 1 written as a
# breadth-first search. Ring 1 must be the neighbour list that trimesh computes from the same faces.

# %%
centre = int(regions["cheeks"][len(regions["cheeks"]) // 2])  # a vertex in the middle of the left cheek
rings = k_rings(faces, V, centre, 6)
assert set(rings[1]) == set(mesh.vertex_neighbors[centre])  # eq. 1's first ring = trimesh's one-ring
assert all(not set(a) & set(b) for i, a in enumerate(rings) for b in rings[i + 1:])  # rings are disjoint
print(f"vertex {centre}: ring sizes {[len(r) for r in rings]}, 3-disk = {sum(len(r) for r in rings[:4])} vertices")
distance = np.full(V, 7.0)
for k, ring in enumerate(rings):
    distance[ring] = k
plot_vertex_map(mesh.vertices, faces, distance, title=f"Rings around vertex {centre} (7 = farther than 6)",
                units="edges", label="ring k", cmap="viridis_r", views=("front",), panel_size=4.2)

# %% [markdown]
# The rings are only regular where the mesh is: most vertices of the template have 6 neighbours, but the
# anchored grid, the mouth and the poles create other valences. A fixed-length spiral has to cope with this.

# %%
# NBVAL_CHECK_OUTPUT
valence = np.array([len(n) for n in mesh.vertex_neighbors])
values, counts = np.unique(valence, return_counts=True)
print("neighbours : " + " ".join(f"{v:>4}" for v in values))
print("vertices   : " + " ".join(f"{c:>4}" for c in counts))

# %% [markdown]
# ## 2. Spirals: one order for the $k$-disk
#
# A convolution needs its inputs in a fixed order, so that weight $W_l$ always meets "the $l$-th neighbour".
# SpiralNet++ (Gong et al., 2019), which EmoFace builds on, lists the centre, then its one-ring in cyclic order,
# then each next ring continuing from where the previous one ended, and truncates the list at a fixed length
# $L$ (the "kernel size" of EmoFace's Table 4: 5, 9 or 18). The readings this package takes:
#
# - the cyclic order follows the triangles' orientation (counter-clockwise seen from outside);
# - the one-ring starts at the **highest neighbour** (largest $y$), so slot 1 means "the neighbour above"
#   at every vertex (SpiralNet++ starts wherever its mesh library's circulator starts);
# - each next ring: every vertex of the last ring, in order, adds its new neighbours, walking round it from the
#   neighbour that entered the spiral last;
# - **dilation** $d$ keeps every $d$-th of the first $L\,d$ entries: the same $L$ weights see farther.

# %%
spirals = spiral_indices(faces, V, length=18, vertices=mesh.vertices)  # (V, 18), dilation 1
check_shape(spirals, (V, 18), "spirals")
assert (spirals[:, 0] == torch.arange(V)).all()  # slot 0 is the centre
row = spirals[centre].tolist()
n1 = len(rings[1])
assert set(row[1:1 + n1]) == set(rings[1])  # then the whole one-ring ...
assert row[1] == max(rings[1], key=lambda u: mesh.vertices[u, 1])  # ... starting at its highest vertex
ring_of_slot = spiral_ring_index(spirals, faces, V, centre)
assert (np.diff(ring_of_slot) >= 0).all()  # rings in order, never back inwards
print("spiral of", centre, ":", row)
print("ring of each slot:", ring_of_slot.tolist())

# %%
centres = [centre, int(mesh.lip_midpoints[0]), int(regions["brows"][len(regions["brows"]) // 3]),
           int(regions["eyes"][2]), int(regions["jaw"][len(regions["jaw"]) // 2])]
plot_spirals(mesh.vertices, faces, spirals, centres, zoom=0.014,
             title="Spirals of length 18 on the template (dilation 1)")

# %% [markdown]
# The close-up shows the order the 18 weights of a layer meet: slot 0 the centre, slots 1-6 the one-ring going
# round from the top, slot 7 on the second ring. How far does a spiral reach? Below, for the lengths and
# dilations of Table 4: the mean number of rings a spiral reaches, and the mean distance (mm, on the template)
# from the centre to its farthest entry. EmoFace adopts $L = 18$, $d = 2$, $\delta = 3$.

# %%
# NBVAL_CHECK_OUTPUT
print(f"{'L':>3} {'dilation':>8} {'rings reached':>13} {'reach (mm)':>10}")
for L, d in ((5, 1), (9, 1), (18, 1), (18, 2), (18, 4)):
    s = spiral_indices(faces, V, length=L, dilation=d, vertices=mesh.vertices)
    reach = np.linalg.norm(mesh.vertices[s.numpy()] - mesh.vertices[:, None], axis=-1).max(1) * 1e3  # (V,)
    last_ring = [spiral_ring_index(s, faces, V, v).max() for v in regions["face"][::10]]
    print(f"{L:>3} {d:>8} {np.mean(last_ring):>13.2f} {reach[regions['face']].mean():>10.1f}")

# %% [markdown]
# ## 3. Boundaries, and where rings run out
#
# FLAME, the mesh of VOCASET and of EmoFace's 3D-RAVDESS, has an open mouth and open eye holes: vertices on
# those edges have an *open* fan of triangles instead of a closed one. Our template is closed (a mouth bag seals
# the lip slit), so let us open it: drop every triangle that touches the bag. The lip vertices become boundary
# vertices, and the bag vertices are left with no triangle at all.

# %%
bag = np.nonzero(mesh.grid["side"] >= 2)[0]  # the mouth-bag vertices behind the lips
open_faces = faces[~np.isin(faces, bag).any(1)]
_, boundary_closed = one_ring_order(faces, V, mesh.vertices)
_, boundary_open = one_ring_order(open_faces, V, mesh.vertices)
assert not boundary_closed.any()  # the template is watertight
lip = int(mesh.lip_midpoints[0])
assert boundary_open[mesh.slit].all()  # both lip rows now lie on the edge of the slit
open_spirals = spiral_indices(open_faces, V, length=18, vertices=mesh.vertices)
print(f"open slit: {boundary_open.sum()} boundary vertices, {len(faces) - len(open_faces)} triangles removed")
print(f"upper-lip midpoint {lip}: closed mesh reaches ring {spiral_ring_index(spirals, faces, V, lip).max()}, "
      f"open mesh ring {spiral_ring_index(open_spirals, open_faces, V, lip).max()}")
plot_spirals(mesh.vertices, open_faces, open_spirals, [lip, int(mesh.slit[1, 3])], zoom=0.012,
             title="Open lip slit: spirals stay on their side of the mouth")

# %% [markdown]
# A boundary needs no special rule: its rings are shorter, so a fixed-length spiral just reaches one ring
# further, and the upper lip no longer reads the lower lip through the bag (compare the close-up with section 2).
# Rings *run out* only when a vertex's whole connected component is smaller than the spiral: here the orphaned
# bag vertices, and with `rings=k` (the whole $k$-disk of eq. 1, padded to the largest disk) every vertex
# whose disk is smaller than the largest. **Fallback** (a reading): the missing slots repeat the centre index,
# and `spiral_mask` marks them so that SpiralConv3D reads zeros there, like a CNN's zero padding at an image
# border. (SpiralNet++ fills them with the nearest vertices in space instead.)

# %%
mask_open = spiral_mask(open_spirals)
assert (mask_open[bag].sum(1) == 1).all()  # an orphaned vertex: only its centre slot is real
assert mask_open[np.setdiff1d(np.arange(V), bag)].all()  # everything else fills all 18 slots
by_rings = spiral_indices(faces, V, rings=2, vertices=mesh.vertices)  # the whole 2-disk of every vertex
disk = spiral_mask(by_rings).sum(1).numpy()
print(f"rings=2: L = {by_rings.shape[1]} (largest 2-disk); median disk {int(np.median(disk))} vertices; "
      f"{1 - disk.sum() / by_rings.numel():.0%} of all slots are padding")
assert by_rings.shape[1] == 89 and np.median(disk) == 19  # the numbers the next paragraph quotes
fig, ax = plt.subplots(figsize=(6.5, 3))
ax.hist(disk, bins=np.arange(disk.min(), disk.max() + 2) - 0.5)
ax.set(xlabel="2-disk size (vertices)", ylabel="vertices", yscale="log", title="2-disk sizes on the template")
plt.show()

# %% [markdown]
# The poles of the head (44 neighbours each) blow the largest disk up to 89 slots while the median disk has 19:
# this is why SpiralNet++ and EmoFace use a **fixed length** instead of whole disks.
#
# ## 4. Time: the causal neighbourhood (eq. 2)
#
# In time, SpiralConv3D looks at the same vertex $i$ over the last $\delta$ frames; before the first frame,
# $\mathrm{Pad}(\delta - t)$ supplies the missing ones (zeros by default, or the first frame repeated):
#
# $$cnt_\delta(V_{t,i}) = \begin{cases} \{V_{t-\delta+1,i}, \dots, V_{t-1,i}, V_{t,i}\}, & t \ge \delta \\
# \{\mathrm{Pad}(\delta - t), V_{1,i}, \dots, V_{t,i}\}, & t < \delta \end{cases} \tag{2}$$

# %%
# NBVAL_CHECK_OUTPUT
x_t = torch.arange(1.0, 6.0).reshape(1, 5, 1)  # (B=1, T=5, 1): frame t carries the value t
for pad in ("zeros", "replicate"):
    window = temporal_neighbourhood(x_t, delta=3, pad=pad)[0, :, :, 0]  # (T, δ), oldest frame first
    print(f"{pad:>9}: " + "  ".join(f"t={t + 1}: {window[t].int().tolist()}" for t in range(5)))

# %% [markdown]
# ## 5. SpiralConv3D (eq. 3), step by step
#
# $$\mathrm{SpiralConv3D}(v) = W\, f\big(cnt_\delta(k\text{-disk}(v))\big) + b \tag{3}$$
#
# Three steps: (a) gather the features of the $L$ spiral vertices (zeros at padded slots), (b) stack the last
# $\delta$ frames of that, (c) flatten the $\delta \times L \times C_{in}$ numbers and apply one linear map.
# The package computes exactly this without building the big stacked tensor (it gathers whole vertex rows in
# blocks and sums the $\delta$ frames after the matmul); the from-scratch version must agree with it.

# %%
B, T, C_in, C_out, delta = 2, 7, 3, 4, 3
torch.manual_seed(0)
conv = SpiralConv3D(C_in, C_out, open_spirals, delta=delta)  # the open-slit spirals: some padded slots
x = torch.randn(B, T, V, C_in, generator=gen)  # f: features of every vertex and frame
gathered = x[:, :, open_spirals] * spiral_mask(open_spirals)[..., None]  # (a) (B, T, V, L, C_in)
stacked = temporal_neighbourhood(gathered, delta)  # (b) (B, T, δ, V, L, C_in)
flat = stacked.permute(0, 1, 3, 2, 4, 5).reshape(B, T, V, -1)  # (c) (B, T, V, δ·L·C_in)
scratch = flat @ conv.weight.reshape(C_out, -1).T + conv.bias  # one linear map W, bias b
check_shape(flat, (B, T, V, delta * 18 * C_in), "neighbourhood")
torch.testing.assert_close(conv(x), scratch)
torch.testing.assert_close(conv.gather(x), gathered)
n_params = sum(p.numel() for p in conv.parameters())
assert n_params == C_out * delta * 18 * C_in + C_out
print(f"eq. 3: package == from scratch; {n_params} parameters, the same for all {V} vertices")

# %% [markdown]
# Causality: the output at frame $t$ may depend on frames $t-\delta+1..t$ only. Change frame 4 and look at which
# output frames move: 4, 5 and 6 (one layer, $\delta = 3$), none before.

# %%
x2 = x.clone()
x2[:, 4] += 1.0
moved = (conv(x2) - conv(x)).abs().amax(dim=(0, 2, 3))  # (T,) largest change per output frame
print("largest change per output frame:", [f"{m:.2f}" for m in moved.tolist()])
assert (moved[:4] == 0).all() and (moved[4:] > 0).all()

# %% [markdown]
# ## 6. Relabelling the vertices
#
# Nothing above depends on how the vertices are *numbered*: renumber them (and the faces with them), and the
# spiral of a vertex must list the same vertices, in the same order, under their new numbers. This holds because
# the start is geometric (the highest neighbour) and the rest follows the triangles' orientation.

# %%
perm = np.random.default_rng(0).permutation(V)  # old id i -> new id perm[i]
new_vertices = np.empty_like(mesh.vertices)
new_vertices[perm] = mesh.vertices
new_spirals = spiral_indices(perm[faces], V, length=18, vertices=new_vertices)
assert torch.equal(new_spirals[perm], torch.from_numpy(perm)[spirals])
conv_c = SpiralConv3D(C_in, C_out, spirals, delta=delta)  # on the original numbering
conv_r = SpiralConv3D(C_in, C_out, new_spirals, delta=delta)  # on the new one, with the same W and b
with torch.no_grad():
    conv_r.weight.copy_(conv_c.weight)
    conv_r.bias.copy_(conv_c.bias)
x_new = torch.empty_like(x)
x_new[:, :, perm] = x  # the same features under the new numbers
torch.testing.assert_close(conv_r(x_new)[:, :, perm], conv_c(x))
print("relabelled mesh: same spirals under the new ids, same convolution output")

# %% [markdown]
# ## 7. Mesh Attention on a corpus clip
#
# Section 3.2 of EmoFace: the branch features $F_{e1}, F_{c1}$ (B, T, C) each go through one MLP layer to $C/4$,
# are concatenated and reduced to $F_{audio}$ (B, T, C/16); a learned position embedding $F_{vertices\text{-}emb}$
# (V, C/16) is added to every frame; SpiralConv3D layers turn the (B, T, V, C/16) result into the **Temporal Mesh
# Attention Map** $A \in [0, 1]$ (a sigmoid), and the offsets are fused vertex by vertex and frame by frame:
#
# $$\Delta M = A \odot \Delta M^e + (1 - A) \odot \Delta M^c$$
#
# (the fusion's exact form is not printed in the paper; this convex combination is the reading taken). The
# encoders that produce $F_e, F_c$ come with the EmoFace model; here two fixed random projections of the
# clip's log-mel features stand in for them, and the offsets are the ground truth of an angry clip
# ($\Delta M^e$) and of its neutral twin ($\Delta M^c$).

# %%
name = "SPK01_s02-angry2"
twin = corpus.meta(name)["neutral_twin"]
template = corpus.template(corpus.meta(name)["subject"]).reshape(-1)  # (V*3,)
T_clip = min(corpus.meta(name)["n_frames"], corpus.meta(twin)["n_frames"])  # crop to the shorter clip
emotion_offsets = torch.from_numpy(corpus.vertices(name)[:T_clip] - template)[None].float()  # (1, T, V*3)
content_offsets = torch.from_numpy(corpus.vertices(twin)[:T_clip] - template)[None].float()
mel = LogMelExtractor(fps=corpus.fps)(corpus.wave(name), corpus.meta(name)["n_frames"])[:T_clip]  # (T, 160)
mel = (mel - mel.mean(0)) / (mel.std(0) + 1e-5)  # standardised per band over the clip
C = 64
proj_e, proj_c = torch.randn(160, C, generator=gen) / 160 ** 0.5, torch.randn(160, C, generator=gen) / 160 ** 0.5
emotion_feat, content_feat = (mel @ proj_e)[None], (mel @ proj_c)[None]  # (1, T, C) stand-ins for F_e1, F_c1
paper_spirals = spiral_indices(faces, V, length=18, dilation=2, vertices=mesh.vertices)  # Table 4's choice
torch.manual_seed(0)
att = MeshAttention(V, C, paper_spirals, delta=3, n_layers=2)
with torch.no_grad():
    fused, a = att(emotion_feat, content_feat, emotion_offsets, content_offsets)
check_shape(fused, (1, T_clip, V * 3), "fused offsets")
check_shape(a, (1, T_clip, V), "attention map")
assert ((a >= 0) & (a <= 1)).all()
lo, hi = torch.minimum(emotion_offsets, content_offsets), torch.maximum(emotion_offsets, content_offsets)
assert ((fused >= lo - 1e-7) & (fused <= hi + 1e-7)).all()  # a convex combination lies between the branches
print(f"{name}: {T_clip} frames; A in [{a.min():.3f}, {a.max():.3f}], mean {a.mean():.3f} (untrained)")

# %% [markdown]
# The untrained map sits near 0.5 (a sigmoid of small numbers): both branches count about equally. It moves
# over time with the audio stand-in, but it is almost uniform over the face, because the position embedding
# starts small (std 0.02). Can the module learn *where* each branch should win? A toy target with a known answer:
# the angry clip's offsets on the upper face (eyes, brows, forehead), the neutral twin's elsewhere, i.e.
# $A^* = 1$ on the upper face and $0$ below. Since
# $\Delta M - \Delta M_{target} = (A - A^*)\,(\Delta M^e - \Delta M^c)$, only vertices where the two clips differ
# carry information; we fit $|A - A^*|$ there, upper and lower face
# weighted equally (the lower face differs far more, and an unweighted loss first pushes the shared bias until
# the sigmoid saturates everywhere). 60 Adam steps, Mesh Attention alone; notebook 15 trains the whole EmoFace.

# %%
upper = torch.zeros(V, dtype=torch.bool)
upper[regions["upper_face"]] = True
differ = (emotion_offsets - content_offsets).view(T_clip, V, 3).norm(dim=-1).mean(0) > 1e-4  # (V,) > 0.1 mm
target = torch.where(upper.repeat_interleave(3), emotion_offsets, content_offsets)  # (1, T, V*3)
opt = torch.optim.Adam(att.parameters(), lr=3e-3)
losses = []
for step in range(60):
    a_now = att.attention(emotion_feat, content_feat)[0]  # (T, V)
    loss = 0.5 * (1 - a_now[:, upper & differ]).mean() + 0.5 * a_now[:, ~upper & differ].mean()  # |A - A*|
    opt.zero_grad()
    loss.backward()
    opt.step()
    losses.append(loss.item())
with torch.no_grad():
    fused_fit, a_fit = att(emotion_feat, content_feat, emotion_offsets, content_offsets)
err = [(f - target).abs().max().item() * 1e3 for f in (fused, fused_fit)]  # mm
print(f"|A - A*|: {losses[0]:.3f} -> {losses[-1]:.4f}; worst offset error to the target {err[0]:.2f} -> "
      f"{err[1]:.3f} mm; mean A: upper face {a_fit[0][:, upper & differ].mean():.3f}, "
      f"lower face {a_fit[0][:, ~upper & differ].mean():.3f}")
assert losses[-1] < 0.05 and err[1] < 0.1 * err[0]

# %%
frames = [15, 35]
maps = torch.cat([a[0, frames], a_fit[0, frames]]).numpy()  # (4, V): untrained, then fitted
fig = plot_frames(np.repeat(mesh.vertices[None], 4, 0), faces, colors=maps, cmap="coolwarm", vmin=0.0, vmax=1.0,
                  titles=[f"{w}, t = {f / corpus.fps:.2f} s" for w in ("untrained", "fitted") for f in frames],
                  color_label="A, emotion share", color_units="0-1", units="mm",
                  suptitle="Mesh Attention map on the face: untrained, and after the toy fit")
fig

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.2), layout="constrained", sharey=True)
t_s = np.arange(T_clip) / corpus.fps
for ax, amap, label in ((axes[0], a, "untrained"), (axes[1], a_fit, "after the toy fit")):
    for region in ("brows", "eyes", "mouth", "jaw"):
        ax.plot(t_s, amap[0][:, regions[region]].mean(1), label=region)
    ax.set(xlabel="time (s)", title=f"Mean attention per face region, {label}")
    ax.grid(alpha=0.3)
axes[0].set_ylabel("mean A in the region")
axes[1].legend(fontsize=8, ncols=2)
plt.show()

# %% [markdown]
# The map is learned per vertex, through the position embedding and the spirals. Where the two clips agree (the
# top and back of the head) the loss says nothing; there $A$ is whatever the shared weights give it, and it
# follows its neighbours (the scalp turns red with the forehead). The first frame is slightly off: its temporal
# neighbourhood is zero-padded (eq. 2).
#
# For autoregressive generation the map of the newest frame is needed at every step. Mesh Attention is causal
# and looks back $n_{layers}(\delta - 1)$ frames, so running it on the last `att.receptive_field` frames gives
# the newest frame's map exactly: no need to recompute the whole clip at each step.

# %%
r = att.receptive_field
with torch.no_grad():
    last = att.attention(emotion_feat[:, -r:], content_feat[:, -r:])[:, -1]  # only the last r frames
torch.testing.assert_close(last, a_fit[:, -1])
print(f"receptive field: {r} frames; the windowed map of the last frame equals the full pass")

# %% [markdown]
# ## 8. The fitted map on the talking face, in 3D
#
# Section 7's toy-fitted Mesh Attention on the angry clip: the face shows the fused offsets (template + the
# convex combination of the two branches), coloured by the emotion share $A$ of each vertex and frame (red: the
# emotion branch, blue: the content branch), the map the fit pushed towards "upper face from the emotion".
#
# With a running kernel the cell below shows it live in 3D (drag to orbit, scroll to zoom, the play button or
# the frame slider runs the clip); the committed notebook stores only the widget's placeholder, as in
# notebook 01.

# %%
# NBVAL_IGNORE_OUTPUT
frames_3d = (torch.from_numpy(template) + fused_fit[0]).reshape(T_clip, V, 3).numpy()  # (T, V, 3) metres
viewer = MeshViewer(frames_3d[0], faces, colors=a_fit[0, 0].numpy(), cmap="coolwarm", vmin=0.0, vmax=1.0,
                    width=360, height=360)
display(viewer.player(frames_3d, colors=a_fit[0].numpy()))
print(f"{name}: {T_clip} frames, coloured by the fitted emotion share A")

# %% [markdown]
# ## 9. EmoFace's Table 4 at tiny scale: the stored sweep
#
# EmoFace's Table 4 varies SpiralConv3D's dilation (1, 2, 4), kernel size $L$ (5, 9, 18) and time duration
# $\delta$ (1, 2, 3 frames) in seven rows, measures LVE and EVE, and adopts the fourth row (dilation 2, $L = 18$,
# $\delta = 3$: `blocks.spiral.PAPER_*`). `benchmarks/spiral_sweep.py` trains the seven rows as tiny EmoFace models
# with one recipe, one budget and 3 seeds, and evaluates them on the 48 `test_emo_a` clips. The budget is far below
# the emotional tables' (`results/spiral.md` states it); this cell reads the stored results and trains nothing.

# %%
import json

from dualtalker_lite.files import repo_root

SWEEP_COMMAND = ("python benchmarks/spiral_sweep.py --seeds 0 1 2 --epochs 8 --sentences s00 --processes 1 "
                 "--out results/")
sweep = json.loads((repo_root() / "results" / "spiral.json").read_text())
assert sweep["command"] == SWEEP_COMMAND, "results/spiral.json was regenerated: update this cell"
paper = {tuple(r["config"]): (r["lve"], r["eve"]) for r in sweep["paper_table4"]}  # as printed in the paper
adopted = tuple(sweep["adopted"])
ours = {}  # (dilation, L, delta) -> {metric: the values of the seeds that finished}
for cfg, row in zip(map(tuple, sweep["configs"]), sweep["rows"]):
    runs = [r["metrics"] for r in sweep["runs"] if r["row"] == row]
    ours[cfg] = {m: np.array([r[m] for r in runs]) for m in ("lve_euclidean", "eve_euclidean")}
assert sweep["status"] == "Complete." and all(len(v["lve_euclidean"]) == 3 for v in ours.values())  # 3 seeds a row
print(f"{sweep['epochs']} epochs on {sweep['n_train_clips']} clips; {len(sweep['runs'])} of "
      f"{len(sweep['configs']) * len(sweep['seeds'])} runs stored")

# %%
# NBVAL_CHECK_OUTPUT
print(f"{'dil.':>4} {'L':>3} {'δ':>2} | seeds | {'LVE (mm)':>8} | {'EVE (mm)':>8} | paper LVE, EVE")
for cfg, v in ours.items():
    lve, eve = v["lve_euclidean"], v["eve_euclidean"]
    print(f"{cfg[0]:>4} {cfg[1]:>3} {cfg[2]:>2} | {len(lve):>5} | {lve.mean():8.3f} | {eve.mean():8.3f} | "
          f"{paper[cfg][0]:.4f}, {paper[cfg][1]:.4f}" + ("  <- adopted" if cfg == adopted else ""))
seed0 = {cfg: (float(v["lve_euclidean"][0]), float(v["eve_euclidean"][0])) for cfg, v in ours.items()}
assert abs(seed0[adopted][0] - 5.452) < 5e-4  # the stored seed-0 LVE of the adopted row (results/spiral.md)
assert max(e for _, e in seed0.values()) - min(e for _, e in seed0.values()) < 0.05  # EVE barely differs
lve = {cfg: v["lve_euclidean"] for cfg, v in ours.items()}
assert min(lve, key=lambda c: lve[c].mean()) != adopted  # the adopted row is not the lowest LVE here

# %%
labels = [f"d{c[0]} L{c[1]} δ{c[2]}" for c in ours]
x = np.arange(len(ours))
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
for ax, (m, j, what) in zip(axes, (("lve_euclidean", 0, "LVE"), ("eve_euclidean", 1, "EVE"))):
    for k, v in enumerate(ours.values()):  # one dot per finished seed, the mean as a bar
        ax.scatter([k] * len(v[m]), v[m], s=14, color="C0", alpha=0.6)
        ax.hlines(v[m].mean(), k - 0.3, k + 0.3, color="C0")
    ax.set(xticks=x, xticklabels=labels, ylabel=f"{what} here (mm)", title=f"{what}: tiny sweep (dots: seeds)")
    ax.axvspan(list(ours).index(adopted) - 0.45, list(ours).index(adopted) + 0.45, color="grey", alpha=0.15)
    twin = ax.twinx()
    twin.plot(x, [paper[c][j] for c in ours], "s--", color="C1", label="paper's Table 4 (as printed)")
    twin.set_ylabel(f"{what} in the paper (×1e-5, as printed)", color="C1")
    ax.tick_params(axis="x", labelrotation=45)
fig.legend(handles=[axes[0].collections[0], twin.lines[0]], labels=["this sweep, one dot per seed (left axis)",
           "paper's Table 4, as printed (right axis)"], loc="outside lower center", ncols=2, fontsize=8)
fig.suptitle("EmoFace Table 4 analogue (grey: the adopted configuration)")
plt.show()

# %% [markdown]
# **What the stored sweep says.** Three seeds per row (`results/spiral.md` has the error bars and checks the
# paper's three readings with a 2-standard-error rule). None of them reproduces on LVE: every difference between
# the rows, kernel 9 against 5 or 18, dilation 2 against 1 or 4, three frames against one or two, is within seed
# noise (an earlier run from an uncommitted tree had kernel 9 beating 5; the clean re-run does not), and the adopted
# row 4 does not have the lowest LVE (row 7 does here; the paper's own LVE is lowest in row 3 while row 4 has the
# lowest EVE). EVE hardly differs between the
# rows (asserted above): at this budget (8 epochs on 56 clips) the upper face stays near the mean-motion start, so
# the sweep can only speak about LVE. A tiny model trained for a minute is far from the paper's setting; read this
# as the recipe to rerun at a larger budget, not as a verdict on the paper.

# %% [markdown]
# ## Summary
#
# - Eq. 1: rings and $k$-disks come from the face list alone; on our template most vertices have 6 neighbours,
#   the poles 44, so whole disks vary wildly in size.
# - A spiral fixes one order for the disk: centre, one-ring in the triangles' cyclic order from the highest
#   neighbour, then each next ring continuing from the last; truncated to $L$ slots, optionally dilated. The order
#   does not depend on the vertex numbering.
# - Boundaries (an open lip slit) need no rule; where rings run out the slots repeat the centre and are masked
#   to zeros.
# - Eq. 2 looks back $\delta$ frames, padded at the start; eq. 3 is one linear map over the $\delta \times L$
#   neighbourhood, causal, with $C_{out}(\delta L C_{in} + 1)$ parameters shared by every vertex.
# - Mesh Attention turns the two branches' features into a per-vertex, per-frame weight $A \in [0,1]$ and fuses
#   the offsets as $A\,\Delta M^e + (1-A)\,\Delta M^c$.
# - EmoFace's Table 4 (kernel size, dilation, duration) has a tiny-scale benchmark, `benchmarks/spiral_sweep.py`;
#   at this scale (3 seeds) none of its readings reproduces on LVE: every difference is within seed noise.
#
# ## Exercises
#
# 1. Start every one-ring at the *lowest-index* neighbour instead (call `spiral_indices` without `vertices=`).
#    Which check of section 6 fails, and which still holds if you compare each spiral's rings as sets?
# 2. SpiralNet++ fills missing slots with the nearest vertices in space. Write that fallback for the orphaned bag
#    vertices of section 3 and compare how many slots it fills with vertices that are *not* graph neighbours.
# 3. With $L = 18$ and $d = 2$ (the paper's choice), how many distinct vertices does a 2-layer Mesh Attention
#    see around a lip vertex? Count them with two rounds of spiral look-ups.
# 4. Replace the sigmoid map by a two-way softmax over $[z_e, z_c]$ computed from two output channels. Show that
#    it is the same family of maps (hint: $\mathrm{softmax}(z_e, z_c)_1 = \sigma(z_e - z_c)$).
