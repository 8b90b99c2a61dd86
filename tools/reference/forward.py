#!/usr/bin/env python3
"""Plain-PyTorch forward pass of the HOOD (postcvpr) cloth network.

This script re-implements, with nothing but torch, numpy and safetensors, the
forward pass of HOOD's ``postcvpr`` model (github.com/Dolorousrtur/HOOD) exactly
as the parity fixtures in ``shared/fixtures/hood-parity`` describe it:

* inputs: body edges (nearest body vertex of every cloth vertex, kept within
  3 cm), vertex normals, node / mesh-edge / coarse-edge / body-edge features,
  normalised with the frozen statistics stored in the state_dict;
* encoder, 15 message-passing blocks with the DownSample / UpSample of the body
  edges, decoder;
* integration: ``pred_pos = pos + velocity + acc``.

It does the same work as HOOD's ``model(batch, is_training=False)``. In
particular every block passes ALL body vertices (13,380 for the fixture body)
through the node MLP, as HOOD does, although only the ~1,000 vertices that own
a body edge can ever influence the garment. Its timing is therefore a fair
stand-in for HOOD's own, and it is the "reference" column of the Rust
project's ``hood bench --reference``. Not reproduced: torch_geometric's Batch
bookkeeping (Python overhead, no arithmetic) and the normalisation of the
skinned target acceleration at the end of get_position (statistics only,
unused at inference, and it needs the cloth's target positions).

Usage::

    forward.py --scene SCENE.safetensors --weights fixture_weights.safetensors \\
               [--check fixture_io.safetensors] [--time | --serve] [--threads N] \\
               [--runs 10] [--warmup 3]

``--scene`` needs only these keys (anything else is ignored, except the
optional ``world_edge_index`` / ``body_active_idx`` / ``body_vertex_type`` /
``cloth_vertex_type`` which ``--check`` compares or honours):
cloth_rest_pos, cloth_pos, cloth_prev_pos (V,3) f32; cloth_faces (F,3) i64;
cloth_v_mass (V,) f32; cloth_vertex_level (V,) i64; mesh_edge_index (2,E) i64
(directed, both directions); coarse_edge_index0/1/2 (2,E_l) i64; body_pos,
body_prev_pos, body_target_pos (B,3) f32; body_faces (Fb,3) i64;
material_inputs_bending_mu_lambda (3,) f32; timestep (1,) f32.

``--check`` runs the forward once and compares its intermediates with a
``fixture_io.safetensors`` (exit code 1 when pred_pos is off by more than
1e-6 m or decoder_output by more than 1e-4 relative). ``--time`` prints one
line of JSON with the timings of the whole forward (median of ``--runs`` after
``--warmup`` untimed runs, under ``torch.no_grad()``). ``--serve`` times one
forward per request, so that ``hood bench`` can take them in turns with its own
steps: it reads a thread count per line on stdin and answers each with one line
of JSON, the time of one forward at that count (after ``--warmup`` untimed ones
the first time the count is asked), until stdin closes; a first line says it
has loaded the scene and weights and is ready. All other output goes
to stderr.

Environment (CPU is enough)::

    python -m venv venv && . venv/bin/activate
    pip install torch==2.2.2 "numpy<2" safetensors

Conventions (see the fixtures' README): edge_index row 0 = source s, row 1 =
target r; relative features are ``x[s] - x[r]``; messages are
``EdgeMLP([h[r], h[s], e])`` summed into r; y is up; velocities and
accelerations are per frame.
"""

import argparse
import json
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import load_file, safe_open

# --------------------------------------------------------------------------
# Constants of the postcvpr configuration
# --------------------------------------------------------------------------

COLLISION_RADIUS = 0.03  # m; a body edge is kept when the nearest body vertex is this close
LATENT = 128

# HOOD NodeType values
NODE_NORMAL = 0
NODE_OBSTACLE = 1
NODE_OBSTACLE_OMIT = 2
NODE_HANDLE = 3

# HOOD's architecture string (configs/postcvpr.yaml). f = mesh edges, cX = coarse
# level X; "d:" / "u:" mark a level change (DownSample / UpSample of the body
# edges) before that block.
ARCHITECTURE = "f,c0|f,c0|f,c0|d:c0,c1|c0,c1|c0,c1|d:c1|c1|c1|u:c0,c1|c0,c1|c0,c1|u:f,c0|f,c0|f,c0"

# Short name in the architecture string -> edge key (names the processor MLPs;
# HOOD's node-MLP input order is the sorted order of these keys)
EDGE_KEYS = {"f": "mesh_edge", "c0": "coarse_edge0", "c1": "coarse_edge1", "c2": "coarse_edge2"}
WORLD_KEY = "world_edge"

SCENE_KEYS_F32 = [
    "cloth_rest_pos", "cloth_pos", "cloth_prev_pos", "cloth_v_mass",
    "body_pos", "body_prev_pos", "body_target_pos",
    "material_inputs_bending_mu_lambda", "timestep",
]
SCENE_KEYS_I64 = [
    "cloth_faces", "cloth_vertex_level", "mesh_edge_index",
    "coarse_edge_index0", "coarse_edge_index1", "coarse_edge_index2", "body_faces",
]
SCENE_KEYS_OPTIONAL = ["world_edge_index", "body_active_idx", "body_vertex_type", "cloth_vertex_type"]


def log(*args):
    print(*args, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------

def load_scene(path):
    """Loads the keys the forward needs (plus a few optional ones for --check)."""
    with safe_open(path, framework="pt") as f:
        present = set(f.keys())
        missing = [k for k in SCENE_KEYS_F32 + SCENE_KEYS_I64 if k not in present]
        if missing:
            raise SystemExit(f"scene {path} lacks keys: {missing}")
        scene = {}
        for k in SCENE_KEYS_F32:
            scene[k] = f.get_tensor(k).to(torch.float32).contiguous()
        for k in SCENE_KEYS_I64 + [k for k in SCENE_KEYS_OPTIONAL if k in present]:
            scene[k] = f.get_tensor(k).to(torch.int64).contiguous()
    if "cloth_vertex_type" in scene and bool((scene["cloth_vertex_type"] == NODE_HANDLE).any()):
        # Pinned vertices need the cloth's skinned target position, which is not
        # part of the scene layout this script reads.
        raise SystemExit("pinned (HANDLE) cloth vertices are not supported")
    return scene


class Mlp:
    """Linear-ReLU-Linear-ReLU-Linear, optionally followed by LayerNorm (HOOD networks.MLP)."""

    def __init__(self, w, prefix, layer_norm=True):
        mlp_prefix = prefix + (".0.layers" if layer_norm else ".layers")
        self.linears = [(w[f"{mlp_prefix}.{i}.weight"], w[f"{mlp_prefix}.{i}.bias"]) for i in (0, 2, 4)]
        self.ln = (w[prefix + ".1.weight"], w[prefix + ".1.bias"]) if layer_norm else None

    def __call__(self, x):
        (w0, b0), (w1, b1), (w2, b2) = self.linears
        x = torch.relu(F.linear(x, w0, b0))
        x = torch.relu(F.linear(x, w1, b1))
        x = F.linear(x, w2, b2)
        if self.ln is not None:
            x = F.layer_norm(x, (x.shape[-1],), self.ln[0], self.ln[1], 1e-5)
        return x


def parse_architecture(arch):
    """Returns one dict per block: level change before it, its edge keys, its weight prefix.

    Mirrors EncodeProcessDecode.build_model: a new ``levels`` entry starts at
    the first block and at every level change, so block k lives under
    ``levels.{L}.{S}``.
    """
    blocks = []
    level, step = -1, 0
    for i, s in enumerate(arch.split("|")):
        change = None
        if ":" in s:
            change = {"d": "down", "u": "up"}[s[0]]
            s = s.split(":")[-1]
        if i == 0 or change is not None:
            level, step = level + 1, 0
        blocks.append({
            "change": change,
            "keys": [EDGE_KEYS[c] for c in s.split(",")],
            "prefix": f"_learned_model.levels.{level}.{step}",
        })
        step += 1
    return blocks


class Params:
    """The HOOD state_dict, split into the pieces the forward uses."""

    def __init__(self, path):
        raw = load_file(path)
        w = {(k[len("model."):] if k.startswith("model.") else k): v.to(torch.float32) for k, v in raw.items()}
        self.nodetype_embedding = w["nodetype_embedding.weight"]  # (9, 9)
        self.vertexlevel_embedding = w["vertexlevel_embedding.weight"]  # (4, 4)
        self.normalizers = {
            n: {k: w[f"_{n}_normalizer.{k}"] for k in ("_acc_count", "_acc_sum", "_acc_sum_squared")}
            for n in ("node", "mesh_edge", "world_edge", "output")
        }
        self.node_encoder = Mlp(w, "_learned_model.node_encoder")
        self.edge_encoders = {n: Mlp(w, f"_learned_model.edgeset_encoders.{n}")
                              for n in ("mesh", "coarse0", "coarse1", "coarse2", "world")}
        self.decoder = Mlp(w, "_learned_model.decoder", layer_norm=False)
        self.blocks = parse_architecture(ARCHITECTURE)
        for b in self.blocks:
            b["edge_mlps"] = {k: Mlp(w, f"{b['prefix']}.edge_processor_dict.{k}") for k in b["keys"] + [WORLD_KEY]}
            b["node_mlp"] = Mlp(w, f"{b['prefix']}.node_processor_dict.node")
            # HOOD's GraphNetBlock.edge_keys: node-MLP inputs in sorted edge-key order
            b["sorted_keys"] = sorted(set(b["keys"] + [WORLD_KEY]))
            n_in = b["node_mlp"].linears[0][0].shape[1]
            assert n_in == LATENT * (1 + len(b["sorted_keys"])), (b["prefix"], n_in)


# --------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------

def vertex_normals(pos, faces):
    """Area-weighted vertex normals (HOOD VertexNormalsPYG).

    Per face, e0xe1 + e1xe2 + e2xe0 (= 3x the doubled-area normal); summed per
    vertex corner by corner (HOOD scatters each corner into its own slot and
    adds the three slots afterwards, which fixes the summation order), then
    normalised with F.normalize (eps 1e-12).
    """
    v0, v1, v2 = pos[faces[:, 0]], pos[faces[:, 1]], pos[faces[:, 2]]
    e0, e1, e2 = v1 - v0, v2 - v1, v0 - v2
    fn = torch.linalg.cross(e0, e1) + torch.linalg.cross(e1, e2) + torch.linalg.cross(e2, e0)
    acc = torch.zeros(pos.shape[0], 3, 3, dtype=pos.dtype)
    for c in range(3):
        acc[:, c].index_add_(0, faces[:, c], fn)
    return F.normalize(acc.sum(dim=1), dim=-1)


def find_world_edges(cloth_pos, body_pos, radius=COLLISION_RADIUS, body_vertex_type=None, chunk=128):
    """Body ('world') edges: for each cloth vertex its nearest body vertex (k = 1),
    kept if the distance is <= radius and that body vertex is not OBSTACLE_OMIT
    (no fallback to the second nearest).

    HOOD queries an sklearn KDTree in float64; this is the same query by brute
    force, in float64 and in chunks of cloth vertices to bound memory. Body
    vertices outside the cloth's bounding box grown by the radius cannot lie
    within the radius of any cloth vertex, so they are dropped first: the
    result is unchanged and the search costs about what HOOD's KDTree does.
    Returns the (2, E) index [cloth; body], sorted by cloth index like HOOD's.
    """
    lo = cloth_pos.min(dim=0).values - radius
    hi = cloth_pos.max(dim=0).values + radius
    candidates = torch.nonzero(((body_pos >= lo) & (body_pos <= hi)).all(dim=1)).squeeze(1)
    if candidates.numel() == 0:
        return torch.zeros(2, 0, dtype=torch.int64)
    body64 = body_pos[candidates].to(torch.float64)
    nearest_idx, nearest_dist = [], []
    for start in range(0, cloth_pos.shape[0], chunk):
        c = cloth_pos[start:start + chunk].to(torch.float64)
        d = torch.cdist(c, body64, compute_mode="donot_use_mm_for_euclid_dist")
        dist, idx = d.min(dim=1)
        nearest_idx.append(idx)
        nearest_dist.append(dist)
    nearest_idx = candidates[torch.cat(nearest_idx)]
    nearest_dist = torch.cat(nearest_dist)
    keep = nearest_dist <= radius
    if body_vertex_type is not None:
        keep &= body_vertex_type[nearest_idx] != NODE_OBSTACLE_OMIT
    cloth_idx = torch.nonzero(keep).squeeze(1)
    return torch.stack([cloth_idx, nearest_idx[cloth_idx]])


# --------------------------------------------------------------------------
# Normalisation and input features
# --------------------------------------------------------------------------

def normalizer_mean_std(acc):
    """mean / std of a HOOD Normalizer from its accumulators (utils/normalization.py)."""
    count = torch.maximum(acc["_acc_count"], torch.tensor(1.0))
    mean = acc["_acc_sum"] / count
    var = torch.maximum(acc["_acc_sum_squared"] / count - mean.pow(2), torch.tensor(0.0))
    std = torch.maximum(var.sqrt(), torch.tensor(1e-8))
    return mean, std


def normalize(x, acc):
    # Frozen statistics (is_training=False): nothing is accumulated.
    mean, std = normalizer_mean_std(acc)
    return (x - mean) / std


def node_features(n, velocity, type_emb, level_emb, normals, dt, log_mass, material):
    """24 columns: velocity, type embedding (9), level embedding (4), normal, dt,
    log mass, bending/mu/lambda inputs (HOOD Model.add_node_features)."""
    return torch.cat([
        velocity,
        type_emb,
        level_emb,
        normals,
        dt.expand(n, 1),
        log_mass,
        material.expand(n, 3),
    ], dim=-1)


def mesh_edge_features(pos, rest_pos, edge_index, dt, material, acc):
    """12 columns: [x_s - x_r, |.|, X_s - X_r, |.|, dt] normalised, then the
    three material inputs unnormalised (HOOD Model.create_mesh_edge_set)."""
    s, r = edge_index[0], edge_index[1]
    rel = pos[s] - pos[r]
    rel_rest = rest_pos[s] - rest_pos[r]
    n = rel.shape[0]
    raw = torch.cat([
        rel, torch.norm(rel, dim=-1, keepdim=True),
        rel_rest, torch.norm(rel_rest, dim=-1, keepdim=True),
        dt.expand(n, 1),
    ], dim=-1)
    return torch.cat([normalize(raw, acc), material.expand(n, 3)], dim=-1), raw


def world_edge_features(cloth_pos, body_pos, body_target_pos, world_edge_index, dt, acc):
    """9 columns per direction, 'source minus target', both directions normalised
    in one call (HOOD Model.create_world_edge_set).

    cloth2body ('features_direct'): [c - o, |c - o|, c - o', |c - o'|, dt];
    body2cloth ('features_inverse'): the negated differences.
    """
    c, o = world_edge_index[0], world_edge_index[1]
    cp = cloth_pos[c]
    rel = cp - body_pos[o]
    rel_next = cp - body_target_pos[o]
    rel_n = torch.norm(rel, dim=-1, keepdim=True)
    rel_next_n = torch.norm(rel_next, dim=-1, keepdim=True)
    n = rel.shape[0]
    dtc = dt.expand(n, 1)
    direct = torch.cat([rel, rel_n, rel_next, rel_next_n, dtc], dim=-1)
    inverse = torch.cat([-rel, rel_n, -rel_next, rel_next_n, dtc], dim=-1)
    both = normalize(torch.cat([direct, inverse]), acc)
    return both[:n], both[n:], direct, inverse


# --------------------------------------------------------------------------
# Message passing
# --------------------------------------------------------------------------

def edge_update(mlp, h_source, h_target, edge_index, e):
    """Message = EdgeMLP([h_target, h_source, e]) (target first, as HOOD's BaseBlock.message)."""
    s, r = edge_index[0], edge_index[1]
    return mlp(torch.cat([h_target[r], h_source[s], e], dim=-1))


def aggregate(messages, targets, n_targets):
    """Sum of messages into their target nodes (PyG aggr='add')."""
    out = torch.zeros(n_targets, messages.shape[1], dtype=messages.dtype)
    return out.index_add_(0, targets, messages)


def run_block(block, h_cloth, h_body, edges, world):
    """One GraphNetBlock.

    ``edges``: edge key -> (edge_index, latents) of the cloth-cloth sets of this
    block. ``world``: dict with 'index' ([cloth; body]), 'c2b' and 'b2c'
    latents. All updates read the latents from the start of the block.
    Returns the new cloth / body latents, the new cloth-cloth edge latents and
    the new world latents (c2b, b2c).
    """
    n_cloth, n_body = h_cloth.shape[0], h_body.shape[0]
    world_mlp = block["edge_mlps"][WORLD_KEY]
    wi = world["index"]

    # Edge messages. 'world_direct' = body -> cloth, 'world_inverse' = cloth -> body;
    # both use the block's world-edge MLP.
    msg = {k: edge_update(block["edge_mlps"][k], h_cloth, h_cloth, ei, e) for k, (ei, e) in edges.items()}
    b2c_index = torch.stack([wi[1], wi[0]])
    msg_b2c = edge_update(world_mlp, h_body, h_cloth, b2c_index, world["b2c"])
    msg_c2b = edge_update(world_mlp, h_cloth, h_body, wi, world["c2b"])

    # Aggregation per node type and edge key.
    agg_cloth = {k: aggregate(m, edges[k][0][1], n_cloth) for k, m in msg.items()}
    agg_cloth[WORLD_KEY] = aggregate(msg_b2c, wi[0], n_cloth)
    agg_body = {WORLD_KEY: aggregate(msg_c2b, wi[1], n_body)}

    # Node update: [h, agg for every key of the block in sorted order], zeros for
    # keys with no edge set ending at that node type. HOOD updates every node of
    # a node type that receives any edge set, i.e. ALL body vertices here.
    def node_update(h, agg):
        parts = [h] + [agg[k] if k in agg else torch.zeros(h.shape[0], LATENT) for k in block["sorted_keys"]]
        return h + block["node_mlp"](torch.cat(parts, dim=1))

    new_cloth = node_update(h_cloth, agg_cloth)
    new_body = node_update(h_body, agg_body)

    new_edges = {k: (ei, e + msg[k]) for k, (ei, e) in edges.items()}
    return new_cloth, new_body, new_edges, world["c2b"] + msg_c2b, world["b2c"] + msg_b2c


# --------------------------------------------------------------------------
# The forward pass
# --------------------------------------------------------------------------

def forward(scene, params, trace=None):
    """HOOD ``Model.forward(batch, is_training=False)``: prepare_inputs, the
    learned model and get_position. Returns pred_pos (V, 3).

    If ``trace`` is a dict, intermediates are stored in it (for --check).
    """
    cloth_pos = scene["cloth_pos"]
    cloth_prev = scene["cloth_prev_pos"]
    rest_pos = scene["cloth_rest_pos"]
    body_pos = scene["body_pos"]
    body_prev = scene["body_prev_pos"]
    body_target = scene["body_target_pos"]
    dt = scene["timestep"].reshape(1, 1)
    material = scene["material_inputs_bending_mu_lambda"].reshape(1, 3)
    n_cloth, n_body = cloth_pos.shape[0], body_pos.shape[0]

    # ---- prepare_inputs ------------------------------------------------
    # Velocities (SampleCollector.add_velocity): per frame.
    cloth_vel = cloth_pos - cloth_prev
    body_vel = body_pos - body_prev

    # Body edges and the active body set (vertices with at least one body edge).
    world_index = find_world_edges(cloth_pos, body_pos, body_vertex_type=scene.get("body_vertex_type"))
    active = torch.zeros(n_body, dtype=torch.bool)
    active[torch.unique(world_index[1])] = True

    # Node features of every cloth and every body vertex.
    cloth_type = scene.get("cloth_vertex_type", torch.full((n_cloth,), NODE_NORMAL, dtype=torch.int64))
    body_type = scene.get("body_vertex_type", torch.full((n_body,), NODE_OBSTACLE, dtype=torch.int64))
    emb_t, emb_l = params.nodetype_embedding, params.vertexlevel_embedding
    cloth_normals = vertex_normals(cloth_pos, scene["cloth_faces"])
    body_normals = vertex_normals(body_pos, scene["body_faces"])
    x_cloth = node_features(n_cloth, cloth_vel, emb_t[cloth_type], emb_l[scene["cloth_vertex_level"]],
                            cloth_normals, dt, torch.log(scene["cloth_v_mass"]).unsqueeze(1), material)
    minus_one = torch.full((n_body, 1), -1.0)
    x_body = node_features(n_body, body_vel, emb_t[body_type], emb_l[torch.zeros(n_body, dtype=torch.int64)],
                           body_normals, dt, minus_one, minus_one.expand(n_body, 3))

    # Cloth-cloth edge features; one shared normaliser for mesh and all coarse levels.
    acc = params.normalizers
    edge_index = {"mesh_edge": scene["mesh_edge_index"]}
    encoder_of = {"mesh_edge": "mesh"}
    for i in range(3):  # c2 is built, normalised and encoded but never used by a block
        edge_index[f"coarse_edge{i}"] = scene[f"coarse_edge_index{i}"]
        encoder_of[f"coarse_edge{i}"] = f"coarse{i}"
    edge_in = {}
    for key, ei in edge_index.items():
        edge_in[key], raw = mesh_edge_features(cloth_pos, rest_pos, ei, dt, material, acc["mesh_edge"])
        if trace is not None:
            trace[f"raw_{key}"] = raw

    w_c2b, w_b2c, raw_c2b, raw_b2c = world_edge_features(cloth_pos, body_pos, body_target, world_index, dt,
                                                         acc["world_edge"])

    # Node normalisation: one call on [cloth rows; active body rows], material
    # columns (21..23) left as they are.
    x_active = x_body[active]
    both = torch.cat([x_cloth, x_active])
    both = torch.cat([normalize(both[:, :-3], acc["node"]), both[:, -3:]], dim=-1)
    x_cloth_n, x_active_n = both[:n_cloth], both[n_cloth:]

    if trace is not None:
        trace.update(world_edge_index=world_index, body_active_idx=torch.nonzero(active).squeeze(1),
                     cloth_normals=cloth_normals, body_normals=body_normals,
                     in_node_cloth=x_cloth_n, in_node_body_active=x_active_n,
                     raw_node_features_norm_part=torch.cat([x_cloth, x_active])[:, :-3],
                     in_edge_mesh=edge_in["mesh_edge"], in_edge_coarse0=edge_in["coarse_edge0"],
                     in_edge_coarse1=edge_in["coarse_edge1"], in_edge_coarse2=edge_in["coarse_edge2"],
                     in_edge_world_cloth2body=w_c2b, in_edge_world_body2cloth=w_b2c,
                     raw_edge_features_world_cloth2body=raw_c2b, raw_edge_features_world_body2cloth=raw_b2c)

    # ---- encoder ---------------------------------------------------------
    # Cloth and active body nodes in one call; inactive body latents are 0.
    lat = params.node_encoder(torch.cat([x_cloth_n, x_active_n]))
    h_cloth = lat[:n_cloth]
    h_body = torch.zeros(n_body, LATENT)
    h_body[active] = lat[n_cloth:]

    edge_lat = {key: params.edge_encoders[encoder_of[key]](edge_in[key]) for key in edge_index}
    n_w = w_c2b.shape[0]
    w_lat = params.edge_encoders["world"](torch.cat([w_c2b, w_b2c]))
    world = {"index": world_index, "c2b": w_lat[:n_w], "b2c": w_lat[n_w:]}

    if trace is not None:
        trace.update(lat_enc_cloth=h_cloth, lat_enc_body_active=h_body[active],
                     lat_enc_edge_mesh=edge_lat["mesh_edge"], lat_enc_edge_coarse0=edge_lat["coarse_edge0"],
                     lat_enc_edge_coarse1=edge_lat["coarse_edge1"], lat_enc_edge_coarse2=edge_lat["coarse_edge2"],
                     lat_enc_edge_world_cloth2body=world["c2b"], lat_enc_edge_world_body2cloth=world["b2c"])
        trace["n_world_edges_per_block"] = []
        trace["downsample_masks"] = []

    # ---- processor -------------------------------------------------------
    stash = []  # DownSample stack: (old world latents and index, edge mask)
    for k, block in enumerate(params.blocks, start=1):
        if block["change"] == "down":
            # DownSample: keep the body edges whose cloth end is a node of the
            # target edge sets of this level (HOOD takes them from the edge
            # indices); remember the full set and the mask for the UpSample.
            node_mask = torch.zeros(n_cloth, dtype=torch.bool)
            for key in block["keys"]:
                node_mask[torch.unique(edge_index[key].reshape(-1))] = True
            mask = node_mask[world["index"][0]]
            stash.append((world, mask))
            world = {"index": world["index"][:, mask], "c2b": world["c2b"][mask], "b2c": world["b2c"][mask]}
            if trace is not None:
                trace["downsample_masks"].append(mask)
        elif block["change"] == "up":
            # UpSample: restore the full set; edges that were filtered out keep
            # the latents they had when they were removed.
            old, mask = stash.pop()
            c2b, b2c = old["c2b"].clone(), old["b2c"].clone()
            c2b[mask] = world["c2b"]
            b2c[mask] = world["b2c"]
            world = {"index": old["index"], "c2b": c2b, "b2c": b2c}

        edges = {key: (edge_index[key], edge_lat[key]) for key in block["keys"]}
        h_cloth, h_body, new_edges, c2b, b2c = run_block(block, h_cloth, h_body, edges, world)
        for key, (_, e) in new_edges.items():
            edge_lat[key] = e
        world = {"index": world["index"], "c2b": c2b, "b2c": b2c}

        if trace is not None:
            trace[f"lat_block{k:02d}_cloth"] = h_cloth
            trace[f"lat_block{k:02d}_body_active"] = h_body[active]
            trace["n_world_edges_per_block"].append(world["index"].shape[1])

    # ---- decoder and integration (Model.get_position) --------------------
    out = params.decoder(h_cloth)
    mean_out, std_out = normalizer_mean_std(acc["output"])
    acceleration = out * std_out + mean_out
    pred_pos = cloth_pos + cloth_vel + acceleration

    if trace is not None:
        trace.update(decoder_output=out, pred_acceleration=acceleration,
                     pred_velocity=cloth_vel + acceleration, pred_pos=pred_pos)
    return pred_pos


# --------------------------------------------------------------------------
# --check
# --------------------------------------------------------------------------

CHECK_TENSORS = [
    "cloth_normals", "body_normals",
    "in_node_cloth", "in_node_body_active",
    "in_edge_mesh", "in_edge_coarse0", "in_edge_coarse1", "in_edge_coarse2",
    "in_edge_world_cloth2body", "in_edge_world_body2cloth",
    "lat_enc_cloth", "lat_enc_body_active",
    "lat_enc_edge_mesh", "lat_enc_edge_coarse0", "lat_enc_edge_world_cloth2body",
] + [f"lat_block{k:02d}_cloth" for k in range(1, 16)] + [
    "lat_block15_body_active",
    "decoder_output", "pred_acceleration", "pred_pos",
]

PRED_POS_TOL_M = 1e-6
DECODER_REL_TOL = 1e-4


def run_check(scene, params, io_path):
    ref = load_file(io_path)
    trace = {}
    with torch.no_grad():
        forward(scene, params, trace)
    ok = True

    # Graph structure.
    wi = trace["world_edge_index"]
    if "world_edge_index" in scene:
        same = wi.shape == scene["world_edge_index"].shape and bool((wi == scene["world_edge_index"]).all())
        log(f"world_edge_index vs scene: {'identical' if same else 'DIFFERENT'} ({wi.shape[1]} edges)")
        ok &= same
    else:
        log(f"world edges: {wi.shape[1]} (scene has no world_edge_index to compare)")
    if "body_active_idx" in scene:
        act = trace["body_active_idx"]
        same = act.shape == scene["body_active_idx"].shape and bool((act == scene["body_active_idx"]).all())
        log(f"body_active_idx vs scene: {'identical' if same else 'DIFFERENT'} ({act.shape[0]} vertices)")
        ok &= same
    else:
        log(f"active body vertices: {trace['body_active_idx'].shape[0]}")
    counts = trace["n_world_edges_per_block"]
    ref_counts = ref["n_world_edges_per_block"].tolist()
    log(f"world edges per block: {counts} {'==' if counts == ref_counts else '!='} reference")
    ok &= counts == ref_counts
    for i, mask in enumerate(trace["downsample_masks"], start=1):
        r = ref[f"world_edge_mask_downsample{i}"]
        same = mask.shape == r.shape and bool((mask == r).all())
        log(f"world_edge_mask_downsample{i}: {'identical' if same else 'DIFFERENT'} ({int(mask.sum())} of {mask.shape[0]} kept)")
        ok &= same
    # The same masks derived from the vertex levels (level >= 1: in c0 U c1,
    # level >= 2: in c1), which holds when the coarse node sets are nested.
    level = scene["cloth_vertex_level"]
    wc = wi[0]
    m1 = level[wc] >= 1
    m2 = level[wc[m1]] >= 2
    same_lv = bool((m1 == trace["downsample_masks"][0]).all()) and bool((m2 == trace["downsample_masks"][1]).all())
    log(f"downsample masks from cloth_vertex_level: {'identical' if same_lv else 'DIFFERENT'}")

    # Tensors.
    log(f"{'tensor':34s} {'max|err|':>11s} {'max|ref|':>11s} {'rel':>11s}")
    for name in CHECK_TENSORS:
        if name not in ref or name not in trace:
            continue
        a, r = trace[name], ref[name]
        if a.shape != r.shape:
            log(f"{name:34s} SHAPE MISMATCH {tuple(a.shape)} vs {tuple(r.shape)}")
            ok = False
            continue
        err = (a - r).abs().max().item()
        mag = r.abs().max().item()
        rel = err / mag if mag > 0 else float("nan")
        log(f"{name:34s} {err:11.3e} {mag:11.3e} {rel:11.3e}")
        if name == "pred_pos" and not err <= PRED_POS_TOL_M:
            log(f"FAIL: pred_pos max error {err:.3e} m > {PRED_POS_TOL_M:g} m")
            ok = False
        if name == "decoder_output" and not rel <= DECODER_REL_TOL:
            log(f"FAIL: decoder_output relative error {rel:.3e} > {DECODER_REL_TOL:g}")
            ok = False
    log("check: " + ("PASS" if ok else "FAIL"))
    return ok


# --------------------------------------------------------------------------
# --time
# --------------------------------------------------------------------------

def run_timing(scene, params, threads, runs, warmup):
    times = []
    with torch.no_grad():
        for _ in range(warmup):
            forward(scene, params)
        for i in range(runs):
            t0 = time.perf_counter()
            forward(scene, params)
            times.append(time.perf_counter() - t0)
            log(f"run {i + 1}/{runs}: {times[-1]:.4f} s")
    print(json.dumps({
        "vertices": int(scene["cloth_pos"].shape[0]),
        "threads": threads,
        "median_s": float(np.median(times)),
        "min_s": float(min(times)),
        "runs": times,
        "torch": torch.__version__,
    }), flush=True)


def serve(scene, params, warmup):
    # Answers go to the real stdout; anything else printed meanwhile goes to stderr.
    answers, sys.stdout = sys.stdout, sys.stderr

    def answer(**fields):
        print(json.dumps({"vertices": int(scene["cloth_pos"].shape[0]), "torch": torch.__version__, **fields}),
              file=answers, flush=True)

    answer(ready=True)
    warmed = set()
    with torch.no_grad():
        for line in sys.stdin:
            if not line.strip():
                continue
            threads = int(line)
            torch.set_num_threads(threads)
            if threads not in warmed:
                for _ in range(warmup):
                    forward(scene, params)
                warmed.add(threads)
            t0 = time.perf_counter()
            forward(scene, params)
            answer(threads=torch.get_num_threads(), seconds=time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="scene .safetensors (fixture layout, see module docstring)")
    ap.add_argument("--weights", required=True, help="HOOD postcvpr state_dict as .safetensors")
    ap.add_argument("--check", metavar="FIXTURE_IO", help="compare intermediates with this fixture_io.safetensors")
    ap.add_argument("--time", action="store_true", help="time the forward and print one JSON line")
    ap.add_argument("--serve", action="store_true",
                    help="answer each thread count read on stdin with the time of one forward (one JSON line)")
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's default)")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=3)
    args = ap.parse_args()

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    threads = torch.get_num_threads()

    scene = load_scene(args.scene)
    params = Params(args.weights)
    log(f"scene: {scene['cloth_pos'].shape[0]} cloth vertices, {scene['body_pos'].shape[0]} body vertices; "
        f"torch {torch.__version__}, {threads} thread(s)")

    ok = True
    if args.check:
        ok = run_check(scene, params, args.check)
    if args.time:
        run_timing(scene, params, threads, args.runs, args.warmup)
    if args.serve:
        serve(scene, params, args.warmup)
    if not args.check and not args.time and not args.serve:
        with torch.no_grad():
            pred = forward(scene, params)
        log(f"pred_pos: shape {tuple(pred.shape)}, max |pred_pos - pos| = "
            f"{(pred - scene['cloth_pos']).abs().max().item():.6g} m")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
