#!/usr/bin/env python3
"""Loads a 3MF with lib3mf in strict mode and prints a JSON summary of what it found.

Used by the Rust integration tests (tests/export_consumers.rs) as an independent consumer:
    python3 tools/check_3mf.py FILE.3mf
Exit status 0 with JSON on stdout when lib3mf read the file; non-zero with the error otherwise.
Every triangle's property reference is checked against the colour / texture groups it names.
"""
import json
import sys

import lib3mf


def main(path):
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    reader = model.QueryReader("3mf")
    reader.SetStrictModeActive(True)
    reader.ReadFromFile(path)
    out = {
        "lib3mf_version": list(wrapper.GetLibraryVersion()),
        "warnings": [reader.GetWarning(i)[1] for i in range(reader.GetWarningCount())],
        "unit_mm": model.GetUnit() == lib3mf.ModelUnit.MilliMeter,
        "objects": [],
        "colorgroups": {},
        "texture2dgroups": {},
        "textures": [],
    }
    groups = {}
    it = model.GetColorGroups()
    while it.MoveNext():
        g = it.GetCurrentColorGroup()
        ids = list(g.GetAllPropertyIDs())
        groups[g.GetUniqueResourceID()] = set(ids)
        colours = set()
        for pid in ids:
            c = g.GetColor(pid)
            colours.add((c.Red, c.Green, c.Blue))
        out["colorgroups"][str(g.GetUniqueResourceID())] = {
            "count": len(ids),
            "distinct": len(colours),
        }
    it = model.GetTexture2DGroups()
    while it.MoveNext():
        g = it.GetCurrentTexture2DGroup()
        ids = list(g.GetAllPropertyIDs())
        groups[g.GetUniqueResourceID()] = set(ids)
        uvs = [g.GetTex2Coord(pid) for pid in ids]
        tex = g.GetTexture2D()
        out["texture2dgroups"][str(g.GetUniqueResourceID())] = {
            "count": len(ids),
            "texture_path": tex.GetAttachment().GetPath(),
            "u_range": [min(t.U for t in uvs), max(t.U for t in uvs)],
            "v_range": [min(t.V for t in uvs), max(t.V for t in uvs)],
        }
    it = model.GetTexture2Ds()
    while it.MoveNext():
        t = it.GetCurrentTexture2D()
        a = t.GetAttachment()
        out["textures"].append(
            {"path": a.GetPath(), "bytes": a.GetStreamSize(), "content_type": int(t.GetContentType())}
        )
    it = model.GetMeshObjects()
    while it.MoveNext():
        o = it.GetCurrentMeshObject()
        props = o.GetAllTriangleProperties()
        without = sum(1 for p in props if p.ResourceID == 0)
        bad = 0
        for p in props:
            if p.ResourceID == 0:
                continue
            ids = groups.get(p.ResourceID)
            if ids is None or any(p.PropertyIDs[k] not in ids for k in range(3)):
                bad += 1
        out["objects"].append(
            {
                "name": o.GetName(),
                "vertices": o.GetVertexCount(),
                "triangles": o.GetTriangleCount(),
                "manifold_and_oriented": o.IsManifoldAndOriented(),
                "triangles_without_property": without,
                "triangles_with_bad_property": bad,
            }
        )
    build = model.GetBuildItems()
    out["build_items"] = 0
    while build.MoveNext():
        out["build_items"] += 1
    print(json.dumps(out))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: check_3mf.py FILE.3mf")
    try:
        main(sys.argv[1])
    except Exception as e:  # lib3mf raises ELib3MFException with the reason
        sys.exit(f"lib3mf could not read {sys.argv[1]}: {e}")
