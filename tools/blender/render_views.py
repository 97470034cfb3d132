# Renders cac's views with Blender (Cycles, CPU). Driven by src/eval/blender.rs:
#   blender -b --factory-startup -P render_views.py -- job.json
# The job file (written by cac) holds the mesh (OBJ, cac's frame kept: +Y up, no axis change),
# the materials, and per view the camera (Blender matrix, lens, sensor, shift), the sun, the
# ambient (uniform world) level, the ground and the output paths. Per view two images are written:
# the shaded view (RGBA PNG, transparent where the sky is: cac composites its own backdrop) and
# the object's coverage mask (alpha of a second view layer in which the ground is a holdout).
# With an HDR environment (job["world"]) it lights the scene instead of the ambient and sun, and
# the shaded view is written opaque over it.
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
bounces = job.get("bounces", 4)
cy.max_bounces = bounces
cy.diffuse_bounces = min(bounces, 2)
cy.glossy_bounces = min(bounces, 2)
cy.transmission_bounces = min(bounces, 2)
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
# Display values (cac's own shading space): colours and textures are not decoded and the image is
# written as computed. Otherwise colours are decoded from sRGB and the image encoded to it.
display_values = bool(job.get("display_values", False))
# cac's surfaces (with display values only): Lambert + Fresnel-weighted GGX gloss, cac's sky in
# reflections; without them, Principled BSDF. cac's ambient (with cac's surfaces only): an
# unoccluded emission; without it, the uniform world.
cac_surfaces = display_values and bool(job.get("cac_surfaces", False))
cac_ambient = cac_surfaces and bool(job.get("cac_ambient", False))
scene.view_settings.view_transform = "Raw" if display_values else "Standard"
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
    img.colorspace_settings.name = "sRGB" if colour and not display_values else "Non-Color"
    return img


paint_nodes = []
# cac's surfaces carry cac's ambient term, albedo × ambient whatever occludes the sky, as an
# emission whose strength is set per view: the ambient with cac's ambient (the world then lights
# glossy rays only), else 0 (the world lights every ray).
ambient_nodes = []


def cac_like(nt, albedo_out, col, gloss, roughness):
    """cac's surface model from Cycles' parts: a Lambert diffuse of the albedo (no energy taken
    by the coat), a GGX glossy lobe weighted by gloss × dielectric Fresnel (F0 = 0.04) for the
    highlight and the mirror term, and the albedo × ambient emission (see ambient_nodes)."""
    diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
    em = nt.nodes.new("ShaderNodeEmission")
    if albedo_out is None:
        diff.inputs["Color"].default_value = col
        em.inputs["Color"].default_value = col
    else:
        nt.links.new(albedo_out, diff.inputs["Color"])
        nt.links.new(albedo_out, em.inputs["Color"])
    ambient_nodes.append(em)
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(diff.outputs["BSDF"], add.inputs[0])
    nt.links.new(em.outputs["Emission"], add.inputs[1])
    if gloss <= 0.0:
        return add.outputs["Shader"]
    glossy = nt.nodes.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "GGX"
    glossy.inputs["Roughness"].default_value = roughness
    fres = nt.nodes.new("ShaderNodeFresnel")
    fres.inputs["IOR"].default_value = 1.5
    weight = nt.nodes.new("ShaderNodeMath")
    weight.operation = "MULTIPLY"
    weight.inputs[1].default_value = gloss
    nt.links.new(fres.outputs["Fac"], weight.inputs[0])
    nt.links.new(weight.outputs[0], glossy.inputs["Color"])
    add2 = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(add.outputs["Shader"], add2.inputs[0])
    nt.links.new(glossy.outputs["BSDF"], add2.inputs[1])
    return add2.outputs["Shader"]


def build_material(mat, spec):
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    col = spec["color"] + [1.0]
    albedo = None
    tex = spec.get("texture")
    if spec["paintable"] or tex:
        t = nt.nodes.new("ShaderNodeTexImage")
        t.interpolation = "Linear"
        t.extension = "REPEAT"
        if tex:
            t.image = image(tex)
        if spec["paintable"]:
            paint_nodes.append(t)
            albedo = t.outputs["Color"]
        else:
            mix = nt.nodes.new("ShaderNodeMixRGB")
            mix.blend_type = "MULTIPLY"
            mix.inputs["Fac"].default_value = 1.0
            mix.inputs["Color2"].default_value = col
            nt.links.new(t.outputs["Color"], mix.inputs["Color1"])
            albedo = mix.outputs["Color"]
    if cac_surfaces:
        # The job's Principled "specular" is F0 / 0.08 = 0.5 × cac's gloss.
        shader = cac_like(nt, albedo, col, 2.0 * spec["specular"], spec["roughness"])
    else:
        bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Roughness"].default_value = spec["roughness"]
        bsdf.inputs["Specular"].default_value = spec["specular"]
        bsdf.inputs["Metallic"].default_value = 0.0
        bsdf.inputs["Base Color"].default_value = col
        if albedo is not None:
            nt.links.new(albedo, bsdf.inputs["Base Color"])
        shader = bsdf.outputs["BSDF"]
    nt.links.new(shader, out.inputs["Surface"])


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
gtex = gnt.nodes.new("ShaderNodeTexImage")
gtex.interpolation = "Linear"
gtex.extension = "REPEAT"
if cac_surfaces:
    gshader = cac_like(gnt, gtex.outputs["Color"], None, 0.0, 1.0)
else:
    gdiff = gnt.nodes.new("ShaderNodeBsdfDiffuse")
    gnt.links.new(gtex.outputs["Color"], gdiff.inputs["Color"])
    gshader = gdiff.outputs["BSDF"]
gnt.links.new(gshader, gout.inputs["Surface"])
gmesh.materials.append(gmat)
ground_images = [image(p) for p in job.get("ground_textures", [])]

# ---- world (uniform ambient) and sun ---------------------------------------------------------
world = bpy.data.worlds.new("ambient")
world.use_nodes = True
wnt = world.node_tree
bg = wnt.nodes["Background"]
bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
scene.world = world
# With sky reflections (always with cac's surfaces), glossy rays see cac's reflected sky: horizon
# to zenith by sqrt(max(y, 0)) of the ray's direction (cac's frame, +Y up), at full strength;
# other rays see the uniform ambient (black with cac's ambient: the ambient term is then the
# materials' emission). The world is not sampled as a light, so that each ray sees the world its
# kind sees (a uniform world is found as well by BSDF sampling).
sky_nodes = None
if cac_surfaces or job.get("sky_reflections", False):
    world.cycles.sampling_method = "NONE"
    coord = wnt.nodes.new("ShaderNodeTexCoord")
    xyz = wnt.nodes.new("ShaderNodeSeparateXYZ")
    wnt.links.new(coord.outputs["Generated"], xyz.inputs["Vector"])
    up = wnt.nodes.new("ShaderNodeMath")
    up.operation = "MAXIMUM"
    up.inputs[1].default_value = 0.0
    wnt.links.new(xyz.outputs["Y"], up.inputs[0])
    root_t = wnt.nodes.new("ShaderNodeMath")
    root_t.operation = "SQRT"
    wnt.links.new(up.outputs[0], root_t.inputs[0])
    sky = wnt.nodes.new("ShaderNodeMixRGB")
    sky.blend_type = "MIX"
    wnt.links.new(root_t.outputs[0], sky.inputs["Fac"])
    path_node = wnt.nodes.new("ShaderNodeLightPath")
    pick = wnt.nodes.new("ShaderNodeMixRGB")
    pick.blend_type = "MIX"
    wnt.links.new(path_node.outputs["Is Glossy Ray"], pick.inputs["Fac"])
    wnt.links.new(sky.outputs["Color"], pick.inputs["Color2"])
    wnt.links.new(pick.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 1.0
    sky_nodes = (sky, pick)

# A photographed HDR environment (job["world"]) replaces the uniform world and the sun: it lights
# the scene (importance-sampled) and is the backdrop. Its up axis (Blender's Z in the image's
# convention) is turned onto cac's +Y, then about +Y by rotation_deg.
world_map = job.get("world")
if world_map is not None:
    name = world_map["image"]
    # system_resource finds folders (a file path gives ''): the folder, then the file in it.
    env_path = name if os.path.isabs(name) else os.path.join(bpy.utils.system_resource(
        "DATAFILES", path=os.path.join("studiolights", "world")), name + ".exr")
    if not env_path or not os.path.isfile(env_path):
        raise SystemExit("cac: no HDR environment %r (looked for %r)" % (name, env_path))
    world.cycles.sampling_method = "AUTOMATIC"
    env = wnt.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(env_path, check_existing=True)
    env.interpolation = "Linear"
    coord = wnt.nodes.new("ShaderNodeTexCoord")
    turn = wnt.nodes.new("ShaderNodeMapping")
    turn.vector_type = "VECTOR"
    turn.inputs["Rotation"].default_value = (math.radians(90.0), 0.0,
                                             math.radians(world_map.get("rotation_deg", 0.0)))
    wnt.links.new(coord.outputs["Generated"], turn.inputs["Vector"])
    wnt.links.new(turn.outputs["Vector"], env.inputs["Vector"])
    wnt.links.new(env.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = world_map.get("strength", 1.0)

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
if world_map is None:
    ct.links.new(rl_image.outputs["Image"], comp.inputs["Image"])
    ct.links.new(rl_image.outputs["Alpha"], comp.inputs["Alpha"])
else:
    # The environment is the backdrop: the camera rays' view of the world (its pass) under the
    # object and ground, written opaque.
    image_layer.use_pass_environment = True
    over = ct.nodes.new("CompositorNodeAlphaOver")
    ct.links.new(rl_image.outputs["Env"], over.inputs[1])
    ct.links.new(rl_image.outputs["Image"], over.inputs[2])
    ct.links.new(over.outputs["Image"], comp.inputs["Image"])
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
    if world_map is not None:
        pass  # the environment's light is the same in every view
    elif sky_nodes is None:
        bg.inputs["Strength"].default_value = v["world_strength"]
    else:
        sky, pick = sky_nodes
        a = 0.0 if cac_ambient else v["world_strength"]
        pick.inputs["Color1"].default_value = (a, a, a, 1.0)
        for em in ambient_nodes:
            em.inputs["Strength"].default_value = v["world_strength"] if cac_ambient else 0.0
        horizon, zenith = v["reflected_sky"]
        sky.inputs["Color1"].default_value = tuple(horizon) + (1.0,)
        sky.inputs["Color2"].default_value = tuple(zenith) + (1.0,)
    s = v.get("sun")
    if s is None or world_map is not None:
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
