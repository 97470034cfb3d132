# Renders cac's views with Blender (Cycles, CPU). Driven by src/eval/blender.rs:
#   blender -b --factory-startup -P render_views.py -- job.json
# The job file (written by cac) holds the mesh (OBJ, cac's frame kept: +Y up, no axis change),
# the materials, and per view the camera (Blender matrix, lens, sensor, shift), the sun, the
# ambient (uniform world) level, the ground and the output paths. Per view two images are written:
# the shaded view (RGBA PNG, transparent where the sky is: cac composites its own backdrop) and
# the object's coverage mask (alpha of a second view layer in which the ground is a holdout).
import json
import math
import os
import sys

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
job_path = argv[0]
with open(job_path) as f:
    job = json.load(f)
root = os.path.dirname(os.path.abspath(job_path))


def path(p):
    return os.path.join(root, p)


# ---- empty scene -------------------------------------------------------------------------
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
cy = scene.cycles
cy.device = "CPU"
cy.samples = job["samples"]
cy.use_adaptive_sampling = False
cy.use_denoising = bool(job.get("denoise", False))
cy.seed = job.get("seed", 0)
cy.max_bounces = 4
cy.diffuse_bounces = 2
cy.glossy_bounces = 2
cy.transmission_bounces = 2
cy.pixel_filter_type = "BOX"
cy.filter_width = 1.0
if job.get("threads", 0) > 0:
    scene.render.threads_mode = "FIXED"
    scene.render.threads = job["threads"]
scene.render.resolution_x = job["width"]
scene.render.resolution_y = job["height"]
scene.render.resolution_percentage = 100
scene.render.pixel_aspect_x = 1.0
scene.render.pixel_aspect_y = 1.0
scene.render.film_transparent = True
scene.render.dither_intensity = 0.0
scene.render.image_settings.file_format = "PNG"
scene.render.image_settings.color_mode = "RGBA"
scene.render.image_settings.color_depth = "8"
scene.view_settings.view_transform = "Standard"
scene.view_settings.look = "None"
scene.view_settings.exposure = 0.0
scene.view_settings.gamma = 1.0
scene.display_settings.display_device = "sRGB"
scene.frame_current = 1

objects = bpy.data.collections.new("Object")
grounds = bpy.data.collections.new("Ground")
scene.collection.children.link(objects)
scene.collection.children.link(grounds)

# ---- the object --------------------------------------------------------------------------
# cac's frame is kept as is (+Y up): the importer's axes are the identity mapping.
bpy.ops.wm.obj_import(filepath=path(job["obj"]), forward_axis="Y", up_axis="Z")
imported = [o for o in bpy.context.selected_objects if o.type == "MESH"]
if not imported:
    raise SystemExit("cac: the OBJ importer produced no mesh")
for o in imported:
    for c in o.users_collection:
        c.objects.unlink(o)
    objects.objects.link(o)
    o.pass_index = 1


def image(p, colour=True):
    img = bpy.data.images.load(path(p), check_existing=True)
    img.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    return img


paint_nodes = []


def build_material(mat, spec):
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    bsdf.inputs["Roughness"].default_value = spec["roughness"]
    bsdf.inputs["Specular"].default_value = spec["specular"]
    bsdf.inputs["Metallic"].default_value = 0.0
    col = spec["color"] + [1.0]
    bsdf.inputs["Base Color"].default_value = col
    tex = spec.get("texture")
    if spec["paintable"] or tex:
        t = nt.nodes.new("ShaderNodeTexImage")
        t.interpolation = "Linear"
        t.extension = "REPEAT"
        if tex:
            t.image = image(tex)
        if spec["paintable"]:
            paint_nodes.append(t)
            nt.links.new(t.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            mix = nt.nodes.new("ShaderNodeMixRGB")
            mix.blend_type = "MULTIPLY"
            mix.inputs["Fac"].default_value = 1.0
            mix.inputs["Color2"].default_value = col
            nt.links.new(t.outputs["Color"], mix.inputs["Color1"])
            nt.links.new(mix.outputs["Color"], bsdf.inputs["Base Color"])


specs = job["materials"]
seen = set()
for o in imported:
    for slot in o.material_slots:
        m = slot.material
        if m is None or m.name in seen:
            continue
        seen.add(m.name)
        # The importer may suffix duplicate names (".001"); match on the stem.
        key = m.name if m.name in specs else m.name.rsplit(".", 1)[0]
        if key not in specs:
            raise SystemExit("cac: material %r of the OBJ is not in the job" % m.name)
        build_material(m, specs[key])

# ---- ground --------------------------------------------------------------------------------
gmesh = bpy.data.meshes.new("ground")
L = job.get("ground_half_size", 1000.0)
gmesh.from_pydata([(-L, 0, -L), (L, 0, -L), (L, 0, L), (-L, 0, L)], [], [(0, 3, 2, 1)])
gmesh.uv_layers.new(name="UVMap")
gobj = bpy.data.objects.new("ground", gmesh)
grounds.objects.link(gobj)
gmat = bpy.data.materials.new("ground")
gmat.use_nodes = True
gnt = gmat.node_tree
gnt.nodes.clear()
gout = gnt.nodes.new("ShaderNodeOutputMaterial")
gdiff = gnt.nodes.new("ShaderNodeBsdfDiffuse")
gtex = gnt.nodes.new("ShaderNodeTexImage")
gtex.interpolation = "Linear"
gtex.extension = "REPEAT"
gnt.links.new(gtex.outputs["Color"], gdiff.inputs["Color"])
gnt.links.new(gdiff.outputs["BSDF"], gout.inputs["Surface"])
gmesh.materials.append(gmat)
ground_images = [image(p) for p in job.get("ground_textures", [])]

# ---- world (uniform ambient) and sun ---------------------------------------------------------
world = bpy.data.worlds.new("ambient")
world.use_nodes = True
bg = world.node_tree.nodes["Background"]
bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
scene.world = world

sun_data = bpy.data.lights.new("sun", "SUN")
sun_data.angle = math.radians(0.53)
sun = bpy.data.objects.new("sun", sun_data)
scene.collection.objects.link(sun)

cam_data = bpy.data.cameras.new("camera")
cam = bpy.data.objects.new("camera", cam_data)
scene.collection.objects.link(cam)
scene.camera = cam

# ---- two view layers: the image, and the object's coverage (ground as holdout) ---------------
image_layer = scene.view_layers[0]
image_layer.name = "image"
mask_layer = scene.view_layers.new("mask")
mask_layer.samples = job.get("mask_samples", 16)
mask_layer.layer_collection.children["Ground"].holdout = True
flat = bpy.data.materials.new("flat")
mask_layer.material_override = flat

scene.use_nodes = True
ct = scene.node_tree
ct.nodes.clear()
rl_image = ct.nodes.new("CompositorNodeRLayers")
rl_image.layer = "image"
rl_mask = ct.nodes.new("CompositorNodeRLayers")
rl_mask.layer = "mask"
comp = ct.nodes.new("CompositorNodeComposite")
comp.use_alpha = True
ct.links.new(rl_image.outputs["Image"], comp.inputs["Image"])
ct.links.new(rl_image.outputs["Alpha"], comp.inputs["Alpha"])
fo = ct.nodes.new("CompositorNodeOutputFile")
fo.base_path = root
fo.format.file_format = "PNG"
fo.format.color_mode = "BW"
fo.format.color_depth = "16"
ct.links.new(rl_mask.outputs["Alpha"], fo.inputs[0])

# ---- views ----------------------------------------------------------------------------------
for i, v in enumerate(job["views"]):
    c = v["camera"]
    cam_data.type = "PERSP"
    cam_data.sensor_fit = c["sensor_fit"]
    cam_data.sensor_width = c["sensor_width"]
    cam_data.sensor_height = c["sensor_height"]
    cam_data.lens = c["lens"]
    cam_data.shift_x = c["shift_x"]
    cam_data.shift_y = c["shift_y"]
    cam_data.clip_start = c["clip_start"]
    cam_data.clip_end = c["clip_end"]
    from mathutils import Matrix

    cam.matrix_world = Matrix(c["matrix_world"])
    bg.inputs["Strength"].default_value = v["world_strength"]
    s = v.get("sun")
    if s is None:
        sun.hide_render = True
    else:
        sun.hide_render = False
        sun_data.energy = s["strength"]
        sun.matrix_world = Matrix(s["matrix_world"])
    g = v.get("ground")
    if g is None:
        gobj.hide_render = True
    else:
        gobj.hide_render = False
        gtex.image = ground_images[g["texture"]]
        uv = gmesh.uv_layers["UVMap"].data
        for loop in gmesh.loops:
            uv[loop.index].uv = g["uv"][loop.vertex_index]
    if paint_nodes and v.get("paint_texture"):
        img = image(v["paint_texture"])
        for t in paint_nodes:
            t.image = img
    fo.file_slots[0].path = v["mask_prefix"]
    scene.render.filepath = path(v["out"])
    bpy.ops.render.render(write_still=True)
    print("cac: rendered view %d of %d" % (i + 1, len(job["views"])), flush=True)
