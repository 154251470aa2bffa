"""Writes box-room.gltf and box-room.glb: a tiny room exercising what gilab's glTF loader reads
(node hierarchy with TRS, textured base colour, emissive strength, KHR_materials_specular,
KHR_lights_punctual, a camera). Run once with python3; the outputs are committed. CC0."""
import base64, json, struct, zlib

def png_checker(n=8):
    rows = b""
    for y in range(n):
        rows += b"\x00" + b"".join(bytes((200, 200, 200, 255)) if (x + y) % 2 else bytes((60, 90, 140, 255)) for x in range(n))
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", n, n, 8, 6, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")

def quad(size):
    s = size / 2
    pos = [(-s, 0, -s), (-s, 0, s), (s, 0, s), (s, 0, -s)]
    nrm = [(0, 1, 0)] * 4
    uv = [(0, 0), (0, 4), (4, 4), (4, 0)]
    return pos, nrm, uv, [0, 1, 2, 0, 2, 3]

def cube():
    pos, idx = [], []
    faces = [((1, 0, 0), (0, 1, 0)), ((-1, 0, 0), (0, 1, 0)), ((0, 1, 0), (0, 0, 1)), ((0, -1, 0), (0, 0, 1)), ((0, 0, 1), (0, 1, 0)), ((0, 0, -1), (0, 1, 0))]
    for n, u in faces:
        v = (n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0])
        b = len(pos)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            pos.append(tuple(0.5 * (n[i] + su * u[i] + sv * v[i]) for i in range(3)))
        idx += [b, b + 1, b + 2, b, b + 2, b + 3]
    return pos, idx  # no normals: the loader must generate them

blob = bytearray()
views, accessors = [], []
def add(data, fmt, count, comp, typ, target, minmax=None):
    while len(blob) % 4:
        blob.append(0)
    off = len(blob)
    blob.extend(struct.pack("<" + fmt * count, *data))
    views.append({"buffer": 0, "byteOffset": off, "byteLength": len(blob) - off, "target": target})
    acc = {"bufferView": len(views) - 1, "componentType": comp, "count": count // {"VEC3": 3, "VEC2": 2, "SCALAR": 1}[typ], "type": typ}
    if minmax:
        acc["min"], acc["max"] = minmax
    accessors.append(acc)
    return len(accessors) - 1

meshes = []
p, n, uv, i = quad(6.0)
flat = lambda l: [c for t in l for c in t]
bounds = lambda ps: ([min(q[k] for q in ps) for k in range(3)], [max(q[k] for q in ps) for k in range(3)])
a_p = add(flat(p), "f", 12, 5126, "VEC3", 34962, bounds(p)); a_n = add(flat(n), "f", 12, 5126, "VEC3", 34962)
a_uv = add(flat(uv), "f", 8, 5126, "VEC2", 34962); a_i = add(i, "H", 6, 5123, "SCALAR", 34963)
meshes.append({"name": "floor", "primitives": [{"attributes": {"POSITION": a_p, "NORMAL": a_n, "TEXCOORD_0": a_uv}, "indices": a_i, "material": 0}]})
lp, ln, luv, li = quad(1.0)
lp = [(x, 0, z) for x, _, z in lp]; li = [0, 2, 1, 0, 3, 2]  # wound to face down
b_p = add(flat(lp), "f", 12, 5126, "VEC3", 34962, bounds(lp)); b_i = add(li, "H", 6, 5123, "SCALAR", 34963)
meshes.append({"name": "panel", "primitives": [{"attributes": {"POSITION": b_p}, "indices": b_i, "material": 1}]})
cp, ci = cube()
c_p = add(flat(cp), "f", 72, 5126, "VEC3", 34962, bounds(cp)); c_i = add(ci, "H", 36, 5123, "SCALAR", 34963)
meshes.append({"name": "cube", "primitives": [{"attributes": {"POSITION": c_p}, "indices": c_i, "material": 2}]})
png = png_checker()

doc = {
    "asset": {"version": "2.0", "generator": "gilab scenes/box-room/generate.py"},
    "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_emissive_strength", "KHR_materials_specular"],
    "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "color": [1.0, 0.8, 0.6], "intensity": 8.0}]}},
    "scene": 0,
    "scenes": [{"nodes": [0]}],
    "nodes": [
        {"name": "root", "children": [1, 2, 3, 4, 5], "translation": [0, 0, 0]},
        {"name": "floor", "mesh": 0},
        {"name": "panel", "mesh": 1, "translation": [0, 3.0, 0]},
        {"name": "cube", "mesh": 2, "translation": [0.8, 0.75, -0.5], "rotation": [0, 0.3826834, 0, 0.9238795], "scale": [1.5, 1.5, 1.5]},
        {"name": "lamp", "translation": [-1.5, 1.5, 1.0], "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"name": "camera", "camera": 0, "translation": [0, 1.6, 5.0], "rotation": [-0.0871557, 0, 0, 0.9961947]},
    ],
    "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.05, "aspectRatio": 1.0}}],
    "meshes": meshes,
    "materials": [
        {"name": "checker floor", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0, "roughnessFactor": 0.8}},
        {"name": "panel light", "emissiveFactor": [1.0, 0.9, 0.8], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 6.0}},
         "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0.0}},
        {"name": "lambert cube", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.3, 0.2, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
         "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}},
    ],
    "textures": [{"source": 0}],
    "images": [{"bufferView": None, "mimeType": "image/png"}],
    "accessors": accessors,
    "bufferViews": views,
    "buffers": [{"byteLength": 0}],
}
# The PNG goes into the buffer too, so one blob serves both files.
while len(blob) % 4:
    blob.append(0)
views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
blob.extend(png)
doc["images"][0]["bufferView"] = len(views) - 1
while len(blob) % 4:
    blob.append(0)
doc["buffers"][0]["byteLength"] = len(blob)

gltf = dict(doc)
gltf["buffers"] = [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()}]
with open("box-room.gltf", "w") as f:
    json.dump(gltf, f, indent=1)
js = json.dumps(doc).encode()
js += b" " * ((4 - len(js) % 4) % 4)
glb = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(blob)) + struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
with open("box-room.glb", "wb") as f:
    f.write(glb)
