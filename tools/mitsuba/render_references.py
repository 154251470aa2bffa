#!/usr/bin/env python3
"""Mitsuba 3 reference images for gilab.

For each scene this script
  1. writes the scene as a single-file glTF 2.0 (buffer embedded as a base64 data URI) to
     tests/data/mitsuba/<scene>.gltf, which gilab loads, and
  2. reads that glTF back, builds the same scene in Mitsuba 3 from it (meshes through temporary
     PLY files, materials and lights mapped by the conventions in README.md) and renders it with
     the `path` integrator at three depths to tests/data/mitsuba/<scene>-<depth>.exr,
and writes tests/data/mitsuba/manifest.json (files, depths, spp, timings, image means).

Because the Mitsuba scene is built from the written glTF, both renderers see the same
triangles, the same camera and the same lights by construction.

Needs only mitsuba (variant scalar_rgb) and numpy. See README.md beside it.
"""

import argparse
import base64
import json
import math
import os
import struct
import sys
import tempfile
import time
import zlib

import numpy as np
import mitsuba as mi

VARIANT = "scalar_rgb"
mi.set_variant(VARIANT)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
DEFAULT_OUT = os.path.join(ROOT, "tests", "data", "mitsuba")

SIZE = 64
# (file label, gilab max_depth, Mitsuba max_depth): Mitsuba counts path segments, gilab bounces.
DEPTHS = [("direct", 1, 2), ("onebounce", 2, 3), ("unbounded", 0, -1)]
# Samples per pixel per scene (all three depths), chosen from measured render times so that the
# whole script runs in about 20 minutes on two cores; see README.md.
SPP = {"cornell": 16384, "glossy": 32768, "punctual": 32768}

METAL_ROUGHNESS = 0.5          # glossy scene: GGX alpha = 0.25
SPOT_OUTER = math.radians(30.0)  # punctual scene: spot half-angle
SPOT_EDGE = 0.001              # glTF innerConeAngle = outer - SPOT_EDGE (rad): a hard edge


# --------------------------------------------------------------------------------------------
# Small linear-algebra helpers


def normalize(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def basis_looking(direction, up):
    """Rotation whose columns are (right, up, -forward): a glTF node looking down -Z along
    `direction`, with +Y as close to `up` as possible."""
    f = normalize(direction)
    r = normalize(np.cross(f, up))
    u = np.cross(r, f)
    return np.stack([r, u, -f], axis=1)


def quat_from_matrix(m):
    """Unit quaternion (x, y, z, w) of a proper rotation matrix."""
    t = m[0, 0] + m[1, 1] + m[2, 2]
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    q = np.array(q)
    return q / np.linalg.norm(q)


def matrix_from_quat(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def node_matrix(node):
    """Local 4x4 transform of a glTF node (matrix or TRS)."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    s = np.diag(node.get("scale", [1.0, 1.0, 1.0]))
    m[:3, :3] = matrix_from_quat(node.get("rotation", [0.0, 0.0, 0.0, 1.0])) @ s
    m[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return m


# --------------------------------------------------------------------------------------------
# Scenes, in a renderer-neutral form:
#   objects:   [(name, positions (N,3), triangles (M,3) counter-clockwise front, material name)]
#   materials: {name: {"kind": "lambert", "color"} | {"kind": "metal", "roughness"}
#                     | {"kind": "emitter", "radiance"}}
#   lights:    [{"kind": "point"|"spot", "position", "color", "intensity", ("target", "outer")}]
#   camera:    {"position", "rotation" (glTF basis: right, up, -forward), "yfov" (radians)}


def cornell_source():
    """Geometry, reflectances, light and camera of Mitsuba's built-in Cornell box
    (mi.cornell_box()), read by loading each shape on its own."""
    d = mi.cornell_box()
    objects = []
    emitter_radiance = None
    for key, v in d.items():
        if not isinstance(v, dict) or v.get("type") not in ("rectangle", "cube"):
            continue
        shape = mi.load_dict({k: x for k, x in v.items() if k not in ("bsdf", "emitter")})
        pos = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        tris = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        # Winding must agree with Mitsuba's own vertex normals, as the light's emitting side
        # (and gilab's generated flat normals) follow the winding.
        nrm = np.array(shape.vertex_normals_buffer(), dtype=np.float64).reshape(-1, 3)
        for t in tris:
            fn = np.cross(pos[t[1]] - pos[t[0]], pos[t[2]] - pos[t[0]])
            assert np.dot(fn, nrm[t].sum(axis=0)) > 0, f"{key}: winding disagrees with normals"
        material = v["bsdf"]["id"]
        if "emitter" in v:
            assert v["emitter"]["type"] == "area"
            emitter_radiance = [float(c) for c in v["emitter"]["radiance"]["value"]]
            material = "light"
        objects.append((key, pos, tris, material))
    reflectance = {k: [float(c) for c in v["reflectance"]["value"]]
                   for k, v in d.items() if isinstance(v, dict) and v.get("type") == "diffuse"}
    s = d["sensor"]
    assert s["type"] == "perspective" and s["fov_axis"] == "smaller"  # square image: = y fov
    to_world = np.array(s["to_world"].matrix, dtype=np.float64)
    # Mitsuba's camera looks down +Z with +X to the image's left; glTF's down -Z with +X right.
    rotation = to_world[:3, :3] @ np.diag([-1.0, 1.0, -1.0])
    camera = {"position": to_world[:3, 3], "rotation": rotation, "yfov": math.radians(s["fov"])}
    return {"objects": objects, "reflectance": reflectance, "radiance": emitter_radiance,
            "camera": camera, "sensor_to_world": to_world}


def make_scenes(src):
    lambert = {k: {"kind": "lambert", "color": c} for k, c in src["reflectance"].items()}
    base = {"camera": src["camera"], "lights": []}

    cornell = dict(base, name="cornell", objects=src["objects"],
                   materials=dict(lambert, light={"kind": "emitter", "radiance": src["radiance"]}))

    glossy_objects = [(n, p, t, "metal" if n in ("floor", "large-box") else m)
                      for n, p, t, m in src["objects"]]
    glossy = dict(base, name="glossy", objects=glossy_objects,
                  materials=dict(lambert, metal={"kind": "metal", "roughness": METAL_ROUGHNESS},
                                 light={"kind": "emitter", "radiance": src["radiance"]}))

    punctual = dict(base, name="punctual",
                    objects=[o for o in src["objects"] if o[3] != "light"],
                    materials=dict(lambert),
                    lights=[
                        # Warm point light, upper left, in front of the tall box.
                        {"kind": "point", "position": [-0.5, 0.75, 0.25],
                         "color": [1.0, 0.8, 0.6], "intensity": 1.2},
                        # Cool spot from the upper left front, aimed down-right at the short box's top.
                        {"kind": "spot", "position": [-0.4, 0.85, 0.6],
                         "target": [0.335, -0.4, 0.38], "color": [0.8, 0.9, 1.0],
                         "intensity": 2.8, "outer": SPOT_OUTER},
                    ])
    return [cornell, glossy, punctual]


# --------------------------------------------------------------------------------------------
# glTF writer


def gltf_material(name, m):
    if m["kind"] == "lambert":
        return {"name": name, "doubleSided": True,
                "pbrMetallicRoughness": {"baseColorFactor": list(m["color"]) + [1.0],
                                         "metallicFactor": 0.0, "roughnessFactor": 1.0},
                "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}}
    if m["kind"] == "metal":
        return {"name": name, "doubleSided": True,
                "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                         "metallicFactor": 1.0,
                                         "roughnessFactor": m["roughness"]}}
    if m["kind"] == "emitter":
        # emissiveFactor must lie in [0, 1]: the largest component goes into the strength.
        strength = max(m["radiance"])
        return {"name": name, "doubleSided": False,
                "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0],
                                         "metallicFactor": 0.0, "roughnessFactor": 1.0},
                "emissiveFactor": [c / strength for c in m["radiance"]],
                "extensions": {"KHR_materials_specular": {"specularFactor": 0.0},
                               "KHR_materials_emissive_strength": {"emissiveStrength": strength}}}
    raise ValueError(m["kind"])


def write_gltf(scene, path):
    blob = bytearray()
    views, accessors = [], []

    def add(array, comp, typ, target, minmax):
        while len(blob) % 4:
            blob.append(0)
        data = array.tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data),
                      "target": target})
        blob.extend(data)
        acc = {"bufferView": len(views) - 1, "componentType": comp,
               "count": len(array), "type": typ}
        if minmax:
            acc["min"] = [float(x) for x in array.min(axis=0)]
            acc["max"] = [float(x) for x in array.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    material_index = {name: i for i, name in enumerate(scene["materials"])}
    meshes, nodes = [], []
    for name, pos, tris, mat in scene["objects"]:
        p = add(pos.astype("<f4"), 5126, "VEC3", 34962, True)
        idx_type = ("<u2", 5123) if len(pos) < 65536 else ("<u4", 5125)
        i = add(tris.reshape(-1).astype(idx_type[0]), idx_type[1], "SCALAR", 34963, False)
        meshes.append({"name": name, "primitives": [
            {"attributes": {"POSITION": p}, "indices": i, "material": material_index[mat]}]})
        nodes.append({"name": name, "mesh": len(meshes) - 1})

    lights = []
    for k, l in enumerate(scene["lights"]):
        light = {"name": f"{l['kind']}{k}", "type": l["kind"], "color": l["color"],
                 "intensity": l["intensity"]}
        node = {"name": light["name"], "translation": [float(x) for x in l["position"]],
                "extensions": {"KHR_lights_punctual": {"light": k}}}
        if l["kind"] == "spot":
            light["spot"] = {"innerConeAngle": l["outer"] - SPOT_EDGE,
                             "outerConeAngle": l["outer"]}
            d = np.subtract(l["target"], l["position"])
            up = [0.0, 0.0, -1.0] if abs(normalize(d)[1]) > 0.9 else [0.0, 1.0, 0.0]
            node["rotation"] = [float(x) for x in quat_from_matrix(basis_looking(d, up))]
        lights.append(light)
        nodes.append(node)

    cam = scene["camera"]
    nodes.append({"name": "camera", "camera": 0,
                  "translation": [float(x) for x in cam["position"]],
                  "rotation": [float(x) for x in quat_from_matrix(cam["rotation"])]})

    while len(blob) % 4:
        blob.append(0)
    used = ["KHR_materials_specular"]
    if any(m["kind"] == "emitter" for m in scene["materials"].values()):
        used.append("KHR_materials_emissive_strength")
    doc = {
        "asset": {"version": "2.0",
                  "generator": f"gilab tools/mitsuba/render_references.py (Mitsuba {mi.__version__})"},
        "extensionsUsed": used + (["KHR_lights_punctual"] if lights else []),
        "scene": 0,
        "scenes": [{"name": scene["name"], "nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "cameras": [{"type": "perspective",
                     "perspective": {"yfov": cam["yfov"], "aspectRatio": 1.0,
                                     "znear": 0.001, "zfar": 100.0}}],
        "meshes": meshes,
        "materials": [gltf_material(n, m) for n, m in scene["materials"].items()],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64,"
                            + base64.b64encode(bytes(blob)).decode()}],
    }
    if lights:
        doc["extensions"] = {"KHR_lights_punctual": {"lights": lights}}
    with open(path, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")


# --------------------------------------------------------------------------------------------
# glTF reader (only what write_gltf produces) and checks


COMPONENTS = {5126: "<f4", 5125: "<u4", 5123: "<u2", 5121: "u1"}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def read_gltf(path):
    """Parses the file with json, decodes its buffer, checks every accessor (range, count, min/max,
    indices in range) and returns (doc, accessor reader)."""
    with open(path) as f:
        doc = json.load(f)
    assert doc["asset"]["version"] == "2.0"
    for ext in ("KHR_materials_specular", "KHR_materials_emissive_strength", "KHR_lights_punctual"):
        if ext in json.dumps({k: v for k, v in doc.items() if k != "extensionsUsed"}):
            assert ext in doc["extensionsUsed"], f"{ext} used but not declared"
    (buf,) = doc["buffers"]
    prefix = "data:application/octet-stream;base64,"
    assert buf["uri"].startswith(prefix)
    data = base64.b64decode(buf["uri"][len(prefix):])
    assert len(data) == buf["byteLength"]

    def accessor(i):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        dt = np.dtype(COMPONENTS[a["componentType"]])
        n = WIDTH[a["type"]]
        off = v.get("byteOffset", 0) + a.get("byteOffset", 0)
        assert off % dt.itemsize == 0
        assert a["count"] * n * dt.itemsize <= v["byteLength"]
        assert v.get("byteOffset", 0) + v["byteLength"] <= len(data)
        arr = np.frombuffer(data, dtype=dt, count=a["count"] * n, offset=off)
        return arr.reshape(-1, n) if n > 1 else arr

    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            pos = accessor(prim["attributes"]["POSITION"])
            a = doc["accessors"][prim["attributes"]["POSITION"]]
            assert np.allclose(pos.min(axis=0), a["min"]) and np.allclose(pos.max(axis=0), a["max"])
            idx = accessor(prim["indices"])
            assert len(idx) % 3 == 0 and idx.max() < len(pos), mesh["name"]
            assert prim["material"] < len(doc["materials"])
    return doc, accessor


def world_nodes(doc):
    """(node, world matrix) for every node of the default scene."""
    out = []
    stack = [(n, np.eye(4)) for n in doc["scenes"][doc.get("scene", 0)]["nodes"]]
    while stack:
        i, parent = stack.pop()
        node = doc["nodes"][i]
        world = parent @ node_matrix(node)
        out.append((node, world))
        stack.extend((c, world) for c in node.get("children", []))
    return out


def mitsuba_bsdf(m):
    """Mitsuba BSDF (and area emitter) for a glTF material written by gltf_material."""
    pbr = m.get("pbrMetallicRoughness", {})
    ext = m.get("extensions", {})
    base = pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])[:3]
    metallic = pbr.get("metallicFactor", 1.0)
    roughness = pbr.get("roughnessFactor", 1.0)
    specular = ext.get("KHR_materials_specular", {}).get("specularFactor", 1.0)
    strength = ext.get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
    radiance = [c * strength for c in m.get("emissiveFactor", [0.0, 0.0, 0.0])]
    if any(radiance):
        # One-sided emitter that does not reflect (Mitsuba's default BSDF would be 0.5 diffuse).
        assert base == [0.0, 0.0, 0.0] and specular == 0.0 and metallic == 0.0
        assert not m.get("doubleSided", False)
        return ({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
                {"type": "area", "radiance": {"type": "rgb", "value": radiance}})
    if metallic == 0.0 and specular == 0.0:
        inner = {"type": "diffuse", "reflectance": {"type": "rgb", "value": base}}
    elif metallic == 1.0 and base == [1.0, 1.0, 1.0]:
        # gilab: Schlick with F0 = 1, i.e. F = 1; Mitsuba: conductor 'none' (eta 0, k 1), F = 1.
        inner = {"type": "roughconductor", "distribution": "ggx", "alpha": roughness ** 2,
                 "material": "none", "specular_reflectance": 1.0}
    else:
        raise ValueError(f"material {m.get('name')} has no exact Mitsuba counterpart here")
    return {"type": "twosided", "bsdf": inner}, None


def write_ply(path, pos, tris):
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {len(pos)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(tris)}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as f:
        f.write(head.encode())
        f.write(np.asarray(pos, dtype="<f4").tobytes())
        for t in tris:
            f.write(struct.pack("<B3i", 3, *(int(x) for x in t)))


def mitsuba_scene_from_gltf(path, tmpdir):
    """Builds the Mitsuba scene dict of a glTF written by write_gltf."""
    doc, accessor = read_gltf(path)
    scene = {"type": "scene"}
    camera = None
    for node, world in world_nodes(doc):
        if "mesh" in node:
            mesh = doc["meshes"][node["mesh"]]
            for k, prim in enumerate(mesh["primitives"]):
                pos = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
                pos = pos @ world[:3, :3].T + world[:3, 3]
                tris = accessor(prim["indices"]).reshape(-1, 3)
                if np.linalg.det(world[:3, :3]) < 0:
                    tris = tris[:, [0, 2, 1]]
                ply = os.path.join(tmpdir, f"{mesh['name']}-{k}.ply")
                write_ply(ply, pos, tris)
                bsdf, emitter = mitsuba_bsdf(doc["materials"][prim["material"]])
                # No vertex normals: Mitsuba's face normal follows the winding, as glTF's front.
                shape = {"type": "ply", "filename": ply, "face_normals": True, "bsdf": bsdf}
                if emitter:
                    shape["emitter"] = emitter
                scene[f"{mesh['name']}-{k}"] = shape
        light_ref = node.get("extensions", {}).get("KHR_lights_punctual")
        if light_ref is not None:
            l = doc["extensions"]["KHR_lights_punctual"]["lights"][light_ref["light"]]
            intensity = [c * l.get("intensity", 1.0) for c in l.get("color", [1.0, 1.0, 1.0])]
            p = world[:3, 3]
            if l["type"] == "point":
                scene[l["name"]] = {"type": "point", "position": p.tolist(),
                                    "intensity": {"type": "rgb", "value": intensity}}
            elif l["type"] == "spot":
                d = normalize(world[:3, :3] @ [0.0, 0.0, -1.0])
                up = normalize(world[:3, :3] @ [0.0, 1.0, 0.0])
                outer = l["spot"].get("outerConeAngle", math.pi / 4)
                inner = l["spot"].get("innerConeAngle", 0.0)
                # Spot: +Z of its to_world is the axis; intensity is the radiant intensity on axis.
                scene[l["name"]] = {"type": "spot", "intensity": {"type": "rgb", "value": intensity},
                                    "to_world": mi.ScalarTransform4f().look_at(
                                        origin=p.tolist(), target=(p + d).tolist(), up=up.tolist()),
                                    "cutoff_angle": math.degrees(outer),
                                    "beam_width": math.degrees(inner)}
            else:
                raise ValueError(l["type"])
        if "camera" in node and camera is None:
            cam = doc["cameras"][node["camera"]]
            assert cam["type"] == "perspective"
            p = world[:3, 3]
            fwd = normalize(world[:3, :3] @ [0.0, 0.0, -1.0])
            up = normalize(world[:3, :3] @ [0.0, 1.0, 0.0])
            camera = {"type": "perspective", "fov_axis": "y",
                      "fov": math.degrees(cam["perspective"]["yfov"]),
                      "near_clip": 0.001, "far_clip": 100.0,
                      "to_world": mi.ScalarTransform4f().look_at(
                          origin=p.tolist(), target=(p + fwd).tolist(), up=up.tolist()),
                      "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE,
                               "pixel_format": "rgb", "component_format": "float32",
                               "rfilter": {"type": "box"}},
                      "sampler": {"type": "independent", "sample_count": 16}}
    assert camera is not None, "no perspective camera"
    scene["sensor"] = camera
    return scene


# --------------------------------------------------------------------------------------------
# Output images


def write_exr(path, rgb):
    """Uncompressed scanline OpenEXR, channels B, G, R as 32-bit float (one scanline per chunk),
    so that a reader of a few dozen lines (or any EXR library) can load it."""
    h, w, _ = rgb.shape

    def attr(name, typ, value):
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    window = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = (struct.pack("<ii", 20000630, 2)
              + attr("channels", "chlist", chlist)
              + attr("compression", "compression", b"\0")
              + attr("dataWindow", "box2i", window)
              + attr("displayWindow", "box2i", window)
              + attr("lineOrder", "lineOrder", b"\0")
              + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
              + attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
              + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
              + b"\0")
    line_bytes = 3 * w * 4
    first = len(header) + 8 * h
    table = struct.pack(f"<{h}Q", *(first + y * (8 + line_bytes) for y in range(h)))
    data = np.asarray(rgb, dtype="<f4")
    lines = b"".join(struct.pack("<ii", y, line_bytes)
                     + b"".join(data[y, :, c].tobytes() for c in (2, 1, 0)) for y in range(h))
    with open(path, "wb") as f:
        f.write(header + table + lines)
    # Read back through Mitsuba's OpenEXR: bit-identical.
    back = np.array(mi.Bitmap(path), dtype=np.float32)
    assert back.shape == data.shape and np.array_equal(back, data), path



def write_png(path, rgb, scale=4):
    """Tonemapped (clamp, gamma 2.2), nearest-neighbour upscaled 8-bit PNG of an (H, W, 3) image."""
    img = np.clip(np.nan_to_num(rgb), 0.0, 1.0) ** (1.0 / 2.2)
    img = np.repeat(np.repeat((img * 255.0 + 0.5).astype(np.uint8), scale, 0), scale, 1)
    h, w, _ = img.shape
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


# --------------------------------------------------------------------------------------------


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=DEFAULT_OUT, help="output folder (default tests/data/mitsuba)")
    ap.add_argument("--only", nargs="*", help="scenes to render (default: all); the manifest keeps the others")
    ap.add_argument("--spp", type=int, help="override the samples per pixel (for quick trials)")
    ap.add_argument("--preview", help="also write tonemapped PNG previews to this folder")
    ap.add_argument("--gltf-only", action="store_true", help="write the glTF files, render nothing")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)

    src = cornell_source()
    scenes = make_scenes(src)
    manifest_path = os.path.join(args.out, "manifest.json")
    manifest = {"scenes": {}}
    if os.path.exists(manifest_path):
        with open(manifest_path) as f:
            manifest = json.load(f)
    manifest.update({
        "mitsuba_version": mi.__version__,
        "mitsuba_variant": VARIANT,
        "integrator": "path (defaults: rr_depth 5, hide_emitters false)",
        "sampler": "independent, fixed seed per image",
        "pixel_filter": "box",
        "image_size": [SIZE, SIZE],
        "depths": {label: {"gilab_max_depth": g, "mitsuba_max_depth": m} for label, g, m in DEPTHS},
        "conventions": "tools/mitsuba/README.md",
    })
    total = time.perf_counter()
    for scene in scenes:
        name = scene["name"]
        if args.only and name not in args.only:
            continue
        gltf_path = os.path.join(args.out, f"{name}.gltf")
        write_gltf(scene, gltf_path)
        with tempfile.TemporaryDirectory() as tmp:
            scene_dict = mitsuba_scene_from_gltf(gltf_path, tmp)
            if name == "cornell":
                # The camera survives glTF and back unchanged.
                got = np.array(scene_dict["sensor"]["to_world"].matrix)
                assert np.abs(got - src["sensor_to_world"]).max() < 1e-5, got
            if args.gltf_only:
                print(f"{name}: wrote {gltf_path}")
                continue
            mscene = mi.load_dict(scene_dict)
        spp = args.spp or SPP[name]
        entry = {"gltf": f"{name}.gltf", "spp": spp, "renders": []}
        for k, (label, gilab_depth, mitsuba_depth) in enumerate(DEPTHS):
            integrator = mi.load_dict({"type": "path", "max_depth": mitsuba_depth})
            seed = zlib.crc32(f"{name}-{label}".encode()) & 0x7FFFFFFF
            t0 = time.perf_counter()
            img = mi.render(mscene, integrator=integrator, spp=spp, seed=seed)
            seconds = time.perf_counter() - t0
            rgb = np.array(img, dtype=np.float32)
            assert rgb.shape == (SIZE, SIZE, 3) and np.isfinite(rgb).all()
            fname = f"{name}-{label}.exr"
            write_exr(os.path.join(args.out, fname), rgb)
            mean = [float(x) for x in rgb.reshape(-1, 3).mean(axis=0)]
            print(f"{fname}: {spp} spp, {seconds:.1f} s, mean rgb {mean[0]:.5f} {mean[1]:.5f} {mean[2]:.5f}",
                  flush=True)
            if name == "cornell":
                # Red wall (x = -1) on the image's left, green wall on its right.
                left, right = rgb[:, :4].reshape(-1, 3).mean(0), rgb[:, -4:].reshape(-1, 3).mean(0)
                assert left[0] > 2 * left[1] and right[1] > right[0], (left, right)
            if args.preview:
                os.makedirs(args.preview, exist_ok=True)
                write_png(os.path.join(args.preview, f"{name}-{label}.png"), rgb)
            entry["renders"].append({"file": fname, "depth": label, "gilab_max_depth": gilab_depth,
                                     "mitsuba_max_depth": mitsuba_depth, "spp": spp, "seed": seed,
                                     "seconds": round(seconds, 1),
                                     "mean_rgb": [round(x, 6) for x in mean]})
        manifest["scenes"][name] = entry
    if not args.gltf_only:
        with open(manifest_path, "w") as f:
            json.dump(manifest, f, indent=1)
            f.write("\n")
        print(f"total {time.perf_counter() - total:.0f} s; wrote {manifest_path}")


if __name__ == "__main__":
    sys.exit(main())
