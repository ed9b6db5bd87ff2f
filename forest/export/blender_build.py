"""Builds a forest scene inside Blender (``blender -b --python blender_build.py -- manifest.json out.blend``).

This file runs in Blender's own Python (3.4+, ``bpy``; no numpy, no forest):
:mod:`forest.export.blender` writes a manifest (JSON) and raw little-endian
arrays, already in Blender's Z-up world, and this script turns them into
datablocks:

* one mesh object per species (its parts joined, one material slot per part),
  in a hidden collection ``forest_species``, named ``species_<index>_<name>``
  so the collection's alphabetical order is the species index;
* a point cloud mesh ``forest_points`` with point attributes ``species`` (int),
  ``rotation`` (Euler XYZ, radians), ``scale`` (float), ``tint`` (colour) and,
  when the manifest has one, ``bark_tint`` (colour: the tree's bark factor),
  and a Geometry Nodes modifier: Collection Info (separate children) →
  Instance on Points (pick instance by ``species``, rotation, scale), so every
  tree is an instance and the species meshes exist once;
* materials: albedo = base colour × texture RGB × tint (the ``tint`` instance
  attribute, read with an Attribute node of type Instancer) where the part is
  tinted, × the bark factor (the ``bark_tint`` instance attribute, read the
  same way) where the manifest marks the part ``bark``; leaves mix a diffuse
  and a translucent BSDF by their translucency share, under the cuticle's
  glossy lobe where the part has a sheen, and the texture's alpha mixes in a
  transparent BSDF;
* the terrain (textured by the colour map when there is one), the camera
  (animated over the exported frames), a Sun lamp and the World background;
* Cycles settings from ``[render]`` and the Standard view transform, so an
  image compares with forest's own sRGB PNG; ``[render] haze`` as forest's
  aerial perspective in the compositor, from the depth pass.

With ``--render PNG`` it also renders the scene (used by tests, and as a
preview), with ``--coverage`` holding out the terrain and the sky so the
image's alpha is where trees are.
"""

from __future__ import annotations

import json
import math
import sys
from array import array
from pathlib import Path

import bpy


def read(folder: Path, name: str, code: str) -> array:
    """The raw little-endian array ``folder/name`` as an ``array`` of type ``code`` (``"f"``, ``"i"``)."""
    a = array(code)
    a.frombytes((folder / name).read_bytes())
    if sys.byteorder != "little":
        a.byteswap()
    return a


def clear_scene() -> None:
    """Remove every object, mesh, material, light and camera of Blender's start-up file."""
    for coll in (bpy.data.objects, bpy.data.meshes, bpy.data.materials, bpy.data.lights, bpy.data.cameras):
        for block in list(coll):
            coll.remove(block)


def make_mesh(name: str, folder: Path, part: dict):
    """A Blender mesh of a manifest part: triangles, per-vertex uv (``UVMap``) and custom normals, smooth shaded."""
    v = read(folder, part["vertices"], "f")
    f = read(folder, part["faces"], "i")
    n = read(folder, part["normals"], "f")
    uv = read(folder, part["uv"], "f")  # per vertex, Blender convention (v up)
    mesh = bpy.data.meshes.new(name)
    nv, nf = len(v) // 3, len(f) // 3
    mesh.vertices.add(nv)
    mesh.vertices.foreach_set("co", v)
    mesh.loops.add(3 * nf)
    mesh.loops.foreach_set("vertex_index", f)
    mesh.polygons.add(nf)
    mesh.polygons.foreach_set("loop_start", array("i", range(0, 3 * nf, 3)))
    mesh.polygons.foreach_set("loop_total", array("i", [3]) * nf)
    layer = mesh.uv_layers.new(name="UVMap")
    loop_uv = array("f", [0.0]) * (6 * nf)
    for k, vi in enumerate(f):
        loop_uv[2 * k] = uv[2 * vi]
        loop_uv[2 * k + 1] = uv[2 * vi + 1]
    layer.data.foreach_set("uv", loop_uv)
    mesh.update()
    mesh.validate()
    if len(n) == len(v):
        mesh.use_auto_smooth = True
        mesh.normals_split_custom_set_from_vertices([tuple(n[3 * i : 3 * i + 3]) for i in range(nv)])
    mesh.polygons.foreach_set("use_smooth", array("b", [1]) * nf)
    return mesh


def image_node(nodes, path: str):
    """An image texture node for the sRGB PNG at ``path`` (packed into the .blend, straight alpha, linear, clamped)."""
    img = bpy.data.images.load(path, check_existing=True)
    img.colorspace_settings.name = "sRGB"
    img.alpha_mode = "STRAIGHT"
    img.pack()
    node = nodes.new("ShaderNodeTexImage")
    node.image = img
    node.interpolation = "Linear"
    node.extension = "EXTEND"
    return node


def multiply(nodes, links, colour, by):
    """A MixRGB node (Multiply, factor 1) of the outputs ``colour`` × ``by``; returns its output."""
    mul = nodes.new("ShaderNodeMixRGB")
    mul.blend_type = "MULTIPLY"
    mul.inputs["Fac"].default_value = 1.0
    links.new(colour, mul.inputs["Color1"])
    links.new(by, mul.inputs["Color2"])
    return mul.outputs["Color"]


def instancer_colour(nodes, name: str):
    """The colour output of an Attribute node reading the instance attribute ``name`` (type Instancer)."""
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "INSTANCER"
    attr.attribute_name = name
    return attr.outputs["Color"]


def cuticle(nodes, links, leaf, sheen: float, alpha: float, fresnel: list[float]):
    """The leaf cuticle's lobe over ``leaf`` (a shader output): s·F̄(μ)·glossy + (1 − s·F̄(μ))·leaf, returned.

    The glossy is a white GGX lobe of Blender roughness √α (Cycles squares it); F̄(μ) the lobe's mean Fresnel
    reflectance at μ = |cos θ| of the view (the manifest's table at μ = k/(n − 1), read by a linear Color Ramp of
    a Layer Weight's Facing, 1 − |cos θ| at blend ½, the same on both sides of a leaf card).  So the mix
    reflects s·E(μ), forest_path's lobe albedo, and takes it from the leaf's diffuse lobes as forest_path does
    (docs/rendering.md, "Leaf sheen").
    """
    facing = nodes.new("ShaderNodeLayerWeight")
    facing.inputs["Blend"].default_value = 0.5
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.interpolation = "LINEAR"
    n = len(fresnel)
    stops = ramp.color_ramp.elements  # a new ramp's two stops are at 0 and 1: the others go between, in order
    for k in range(1, n - 1):
        stops.new(k / (n - 1))
    for stop, value in zip(stops, reversed(fresnel)):  # facing 0 … 1 is μ 1 … 0
        stop.color = (value, value, value, 1.0)
    links.new(facing.outputs["Facing"], ramp.inputs["Fac"])
    weight = nodes.new("ShaderNodeMath")
    weight.operation = "MULTIPLY"
    links.new(ramp.outputs["Color"], weight.inputs[0])
    weight.inputs[1].default_value = sheen
    gloss = nodes.new("ShaderNodeBsdfGlossy")
    gloss.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    gloss.inputs["Roughness"].default_value = math.sqrt(alpha)
    mix = nodes.new("ShaderNodeMixShader")
    links.new(weight.outputs[0], mix.inputs["Fac"])
    links.new(leaf, mix.inputs[1])
    links.new(gloss.outputs["BSDF"], mix.inputs[2])
    return mix.outputs["Shader"]


def make_material(name: str, part: dict):
    """albedo = colour × texture × tint (tinted parts) × bark factor (bark parts); leaves: (1−τ)·diffuse +
    τ·translucent, under the cuticle's lobe where the part has a sheen (:func:`cuticle`); alpha cuts the card."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    colour = nodes.new("ShaderNodeRGB")
    colour.outputs[0].default_value = (*part["colour"], 1.0)
    albedo = colour.outputs[0]
    tex = None
    if part.get("texture"):
        tex = image_node(nodes, part["texture"])
        albedo = multiply(nodes, links, albedo, tex.outputs["Color"])
    if part.get("tinted"):
        albedo = multiply(nodes, links, albedo, instancer_colour(nodes, "tint"))
    if part.get("bark"):
        albedo = multiply(nodes, links, albedo, instancer_colour(nodes, "bark_tint"))
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(albedo, diffuse.inputs["Color"])
    shader = diffuse.outputs["BSDF"]
    tau = float(part.get("translucency", 0.0))
    if tau > 0:
        trans = nodes.new("ShaderNodeBsdfTranslucent")
        links.new(albedo, trans.inputs["Color"])
        mix = nodes.new("ShaderNodeMixShader")
        mix.inputs["Fac"].default_value = tau
        links.new(shader, mix.inputs[1])
        links.new(trans.outputs["BSDF"], mix.inputs[2])
        shader = mix.outputs["Shader"]
    if float(part.get("sheen", 0.0)) > 0:
        shader = cuticle(
            nodes, links, shader, float(part["sheen"]), float(part["sheen_roughness"]), part["sheen_fresnel"]
        )
    if tex is not None and part.get("alpha", False):
        transparent = nodes.new("ShaderNodeBsdfTransparent")
        mix = nodes.new("ShaderNodeMixShader")
        links.new(tex.outputs["Alpha"], mix.inputs["Fac"])
        links.new(transparent.outputs["BSDF"], mix.inputs[1])
        links.new(shader, mix.inputs[2])
        shader = mix.outputs["Shader"]
        mat.blend_method = "CLIP"
        mat.shadow_method = "CLIP"
    links.new(shader, out.inputs["Surface"])
    return mat


def make_species(manifest: dict, folder: Path):
    """One object per species, its parts joined, in the hidden collection ``forest_species`` (returned)."""
    coll = bpy.data.collections.new("forest_species")
    bpy.context.scene.collection.children.link(coll)
    coll.hide_render = False
    layer_coll = bpy.context.view_layer.layer_collection.children[coll.name]
    layer_coll.exclude = True  # not drawn itself: instanced by the points
    for sp in manifest["species"]:
        meshes = []
        for k, part in enumerate(sp["parts"]):
            m = make_mesh(f"{sp['object']}_part{k}", folder, part)
            m.materials.append(make_material(f"{sp['name']}_{part['kind']}{k}", part))
            meshes.append(m)
        obj = bpy.data.objects.new(sp["object"], meshes[0])
        coll.objects.link(obj)
        if len(meshes) > 1:  # join the parts into one mesh, one material slot each
            others = []
            for m in meshes[1:]:
                o = bpy.data.objects.new(m.name, m)
                coll.objects.link(o)
                others.append(o)
            with bpy.context.temp_override(active_object=obj, selected_editable_objects=[obj, *others], object=obj):
                bpy.ops.object.join()
    return coll


#: The point attributes of ``forest_points``: (name, type, array code, field); those the manifest has are made.
POINT_ATTRIBUTES = (
    ("species", "INT", "i", "value"),
    ("rotation", "FLOAT_VECTOR", "f", "vector"),
    ("scale", "FLOAT", "f", "value"),
    ("tint", "FLOAT_COLOR", "f", "color"),
    ("bark_tint", "FLOAT_COLOR", "f", "color"),
)


def make_points(manifest: dict, folder: Path, coll):
    """The point cloud ``forest_points`` (species, rotation, scale, tint and bark factor per point) instancing
    ``coll``'s species."""
    pts = manifest["points"]
    n = pts["count"]
    mesh = bpy.data.meshes.new("forest_points")
    mesh.vertices.add(n)
    mesh.vertices.foreach_set("co", read(folder, pts["position"], "f"))
    for name, kind, code, field in POINT_ATTRIBUTES:
        if name not in pts:
            continue
        attr = mesh.attributes.new(name, kind, "POINT")
        if n:
            attr.data.foreach_set(field, read(folder, pts[name], code))
    mesh.update()
    obj = bpy.data.objects.new("forest_points", mesh)
    bpy.context.scene.collection.objects.link(obj)
    group = bpy.data.node_groups.new("forest_instances", "GeometryNodeTree")
    group.inputs.new("NodeSocketGeometry", "Geometry")
    group.outputs.new("NodeSocketGeometry", "Geometry")
    nodes, links = group.nodes, group.links
    gin = nodes.new("NodeGroupInput")
    gout = nodes.new("NodeGroupOutput")
    info = nodes.new("GeometryNodeCollectionInfo")
    info.inputs["Collection"].default_value = coll
    info.inputs["Separate Children"].default_value = True
    info.inputs["Reset Children"].default_value = True
    info.transform_space = "ORIGINAL"
    iop = nodes.new("GeometryNodeInstanceOnPoints")
    iop.inputs["Pick Instance"].default_value = True

    def named(name, data_type):
        node = nodes.new("GeometryNodeInputNamedAttribute")
        node.data_type = data_type
        node.inputs["Name"].default_value = name
        return next(o for o in node.outputs if o.enabled and o.name == "Attribute")

    links.new(gin.outputs["Geometry"], iop.inputs["Points"])
    links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    links.new(named("species", "INT"), iop.inputs["Instance Index"])
    links.new(named("rotation", "FLOAT_VECTOR"), iop.inputs["Rotation"])
    links.new(named("scale", "FLOAT"), iop.inputs["Scale"])
    links.new(iop.outputs["Instances"], gout.inputs["Geometry"])
    mod = obj.modifiers.new("forest_instances", "NODES")
    mod.node_group = group
    return obj


def make_terrain(manifest: dict, folder: Path, name: str = "terrain"):
    """The terrain object (or ``horizon``, the hills past its edge), its material the manifest's colour (and
    texture)."""
    t = manifest[name]
    mesh = make_mesh(name, folder, t)
    part = {"colour": t["colour"], "texture": t.get("texture"), "tinted": False, "translucency": 0.0}
    mesh.materials.append(make_material(name, part))
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def make_water(manifest: dict, folder: Path):
    """The ground's water: a mesh whose material is a GGX gloss of the manifest's roughness weighted by the
    Fresnel reflectance of its index over a diffuse of its colour (F·gloss + (1 − F)·diffuse, forest_path's water)."""
    w = manifest["water"]
    mesh = make_mesh("water", folder, w)
    mat = bpy.data.materials.new("water")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*w["colour"], 1.0)
    gloss = nodes.new("ShaderNodeBsdfGlossy")
    gloss.inputs["Roughness"].default_value = float(w["roughness"])
    gloss.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    fresnel = nodes.new("ShaderNodeFresnel")
    fresnel.inputs["IOR"].default_value = float(w["ior"])
    mix = nodes.new("ShaderNodeMixShader")
    links.new(fresnel.outputs["Fac"], mix.inputs["Fac"])
    links.new(diffuse.outputs["BSDF"], mix.inputs[1])
    links.new(gloss.outputs["BSDF"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    mesh.materials.append(mat)
    obj = bpy.data.objects.new("water", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def make_camera(manifest: dict):
    """The scene camera, keyframed per exported frame when there is more than one key."""
    c = manifest["camera"]
    cam = bpy.data.cameras.new("camera")
    cam.sensor_fit = "HORIZONTAL"
    cam.clip_start, cam.clip_end = c["near"], c["far"]
    obj = bpy.data.objects.new("camera", cam)
    bpy.context.scene.collection.objects.link(obj)
    scene = bpy.context.scene
    scene.camera = obj
    from mathutils import Matrix

    for key in c["keys"]:
        obj.matrix_world = Matrix([key["matrix"][4 * i : 4 * i + 4] for i in range(4)])
        if "lens" in key:  # a focal length on a filmback, as the config gives it
            cam.sensor_width = c["sensor_width"]
            cam.lens = key["lens"]
        else:
            cam.angle = math.radians(key["fov"])
        dof = key.get("dof")
        if dof:  # depth of field: Cycles' thin lens of radius lens / (2·f-stop), in focus at focus_distance
            cam.dof.use_dof = True
            cam.dof.aperture_fstop = dof["f_stop"]
            cam.dof.focus_distance = dof["focus_distance"]
        if len(c["keys"]) > 1:
            obj.keyframe_insert("location", frame=key["frame"])
            obj.keyframe_insert("rotation_euler", frame=key["frame"])
            cam.keyframe_insert("lens", frame=key["frame"])
            if dof:
                cam.dof.keyframe_insert("aperture_fstop", frame=key["frame"])
                cam.dof.keyframe_insert("focus_distance", frame=key["frame"])
    return obj


def make_lights(manifest: dict) -> None:
    """A Sun lamp for the manifest's sun and the World background for its sky (constant or envmap); none is black."""
    from mathutils import Matrix

    sun = manifest.get("sun")
    if sun:
        light = bpy.data.lights.new("sun", "SUN")
        light.energy = sun["strength"]
        light.color = sun["colour"]
        light.angle = math.radians(sun["angle"])
        obj = bpy.data.objects.new("sun", light)
        obj.matrix_world = Matrix([sun["matrix"][4 * i : 4 * i + 4] for i in range(4)])
        bpy.context.scene.collection.objects.link(obj)
    world = bpy.data.worlds.new("forest_sky")
    bpy.context.scene.world = world
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    bg = nodes["Background"]
    sky = manifest.get("sky")
    if not sky:
        bg.inputs["Strength"].default_value = 0.0
        return
    bg.inputs["Strength"].default_value = sky["strength"]
    if sky.get("envmap"):
        env = nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(sky["envmap"], check_existing=True)
        coord = nodes.new("ShaderNodeTexCoord")
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Rotation"].default_value[2] = math.radians(sky["rotation_z"])
        links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], env.inputs["Vector"])
        links.new(env.outputs["Color"], bg.inputs["Color"])
    else:
        bg.inputs["Color"].default_value = (*sky["colour"], 1.0)


def set_render(manifest: dict) -> None:
    """Cycles on the CPU with the manifest's samples, seed, bounces, size and frame range; Standard view transform."""
    r = manifest["render"]
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = r["spp"]
    scene.cycles.use_denoising = False
    scene.cycles.seed = r["seed"]
    scene.cycles.max_bounces = max(0, r["max_depth"] - 1)
    scene.cycles.transparent_max_bounces = 64
    scene.render.resolution_x, scene.render.resolution_y = r["width"], r["height"]
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.render.fps = max(1, round(r["fps"]))
    scene.frame_start, scene.frame_end = r["frame_start"], r["frame_end"]
    scene.frame_set(r["frame_start"])
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0


def make_haze(manifest: dict) -> None:
    """forest's aerial perspective, L·e^(−σd) + H·(1 − e^(−σd)) on surfaces, in the compositor.

    d is Cycles' depth pass (distance along the view axis: within cos(fov/2) of
    forest's distance along the ray); sky pixels keep their colour.
    """
    r = manifest["render"]
    if r.get("haze", 0.0) <= 0:
        return
    scene = bpy.context.scene
    bpy.context.view_layer.use_pass_z = True
    scene.use_nodes = True
    nodes, links = scene.node_tree.nodes, scene.node_tree.links
    nodes.clear()
    layers = nodes.new("CompositorNodeRLayers")

    def math(op, a, b):
        node = nodes.new("CompositorNodeMath")
        node.operation = op
        for k, v in enumerate((a, b)):
            if isinstance(v, (int, float)):
                node.inputs[k].default_value = float(v)
            else:
                links.new(v, node.inputs[k])
        return node.outputs[0]

    depth = layers.outputs["Depth"]
    transmitted = math("EXPONENT", math("MULTIPLY", depth, -float(r["haze"])), 0.0)
    fac = math("MULTIPLY", math("SUBTRACT", 1.0, transmitted), math("LESS_THAN", depth, 1e9))
    mix = nodes.new("CompositorNodeMixRGB")
    links.new(fac, mix.inputs["Fac"])
    links.new(layers.outputs["Image"], mix.inputs[1])
    mix.inputs[2].default_value = (*r["haze_colour"], 1.0)
    out = nodes.new("CompositorNodeComposite")
    links.new(mix.outputs["Image"], out.inputs["Image"])


def main(argv: list[str]) -> None:
    """Build the .blend from ``blender ... -- manifest.json out.blend [--render PNG [--coverage]]``, save it, render."""
    args = argv[argv.index("--") + 1 :] if "--" in argv else []
    manifest_path, out = Path(args[0]), Path(args[1])
    render_to = args[args.index("--render") + 1] if "--render" in args else None
    coverage = "--coverage" in args
    folder = manifest_path.parent
    manifest = json.loads(manifest_path.read_text())
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups beside the output
    clear_scene()
    coll = make_species(manifest, folder)
    make_points(manifest, folder, coll)
    terrain = make_terrain(manifest, folder)
    horizon = make_terrain(manifest, folder, "horizon") if manifest.get("horizon") else None
    water = make_water(manifest, folder) if manifest.get("water") else None
    make_camera(manifest)
    make_lights(manifest)
    set_render(manifest)
    make_haze(manifest)
    bpy.ops.wm.save_as_mainfile(filepath=str(out), compress=True)
    if render_to:
        scene = bpy.context.scene
        if coverage:  # alpha = trees: the terrain held out, the sky transparent, samples kept in their pixel
            terrain.is_holdout = True
            for obj in (horizon, water):
                if obj is not None:
                    obj.is_holdout = True
            scene.render.film_transparent = True
            scene.use_nodes = False  # no haze over the alpha
            scene.cycles.filter_width = 0.01
        scene.render.image_settings.file_format = "PNG"
        scene.render.image_settings.color_mode = "RGBA"
        scene.render.filepath = render_to
        bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    main(sys.argv)
