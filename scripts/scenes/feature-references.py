#!/usr/bin/env python3
"""The scene-reader feature scenes and their Mitsuba 3 reference means.

Writes crates/nis-render/tests/scenes/features/*.xml (one small scene per feature the reader
supports: filters, BSDFs, spectra, emitters, shapes, Mitsuba 0.x names, integrator plugins),
renders each with Mitsuba 3 (scalar_rgb) over several seeds, and writes their mean radiance, the
means of the image's four quadrants (which see a flipped texture or a mirrored camera) and
their standard errors to mitsuba-means.json beside them; `tests/mitsuba_features.rs` renders the
same files with nis-render and compares. A scene that Mitsuba 3 itself cannot read as written
(a Mitsuba 0.4 `<lookAt>`, a guiding paper's integrator plugin) is rendered from its Mitsuba 3
twin, which says the same thing in Mitsuba 3's words.

    python3 -m venv target/mitsuba-venv && target/mitsuba-venv/bin/pip install mitsuba==3.9.1
    target/mitsuba-venv/bin/python scripts/scenes/feature-references.py [--spp 4096] [--seeds 4]
"""
import argparse
import json
import math
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "crates/nis-render/tests/scenes/features"
RES = 24

BASE = """<?xml version="1.0" encoding="utf-8"?>
<!-- nis-render feature scene '{name}' (scripts/scenes/feature-references.py writes it). -->
<scene version="{version}">
    <default name="spp" value="64"/>
    {integrator}
    {sensor}
        <sampler type="independent">
            <integer name="sample_count" value="$spp"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/>
            {filter}
        </film>
    </sensor>
    {defs}
    {floor_shape}
    <shape type="sphere">
        <point name="center" x="0" y="0.5" z="0"/>
        <float name="radius" value="0.5"/>
        {sphere}
    </shape>
    {light}
</scene>
"""

AREA = """<shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.5"/><translate x="0.4" y="2.2" z="0.3"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 11, 10"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.15, 0.2, 0.25"/></emitter>"""

FLOOR = """<shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="2"/></transform>
        {bsdf}
    </shape>"""
CHECKS = """<texture type="checkerboard" id="checks">
        <transform name="to_uv"><scale x="6" y="6"/></transform>
    </texture>"""
PERSPECTIVE = """<sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0, 1.6, 3" target="0, 0.4, 0" up="0, 1, 0"/>
        </transform>"""
DIFFUSE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.55, 0.5"/></bsdf>'
PATH = '<integrator type="path"><integer name="max_depth" value="8"/></integrator>'
BOX = '<rfilter type="box"/>'


def scene(name, *, floor=DIFFUSE, sphere=DIFFUSE, light=AREA, integrator=PATH, rfilter=BOX,
          version="3.0.0", sensor=PERSPECTIVE):
    """A feature scene; `floor` is the floor's BSDF, or a whole `<shape>` in its place."""
    if floor.startswith("<shape"):
        floor_shape = floor
    else:
        floor_shape = FLOOR.format(bsdf=floor)
    return BASE.format(name=name, version=version, integrator=integrator, res=RES, sensor=sensor,
                       filter=rfilter, floor_shape=floor_shape, sphere=sphere, light=light,
                       defs=CHECKS if 'id="checks"' in floor else "")


def features():
    """(name, our XML, Mitsuba 3's XML or None when it reads ours as written)."""
    out = []

    def add(name, mitsuba=None, **kw):
        out.append((name, scene(name, **kw), mitsuba))

    add("filter-gaussian", rfilter="")
    add("filter-tent", rfilter='<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>')
    add("plastic", sphere='<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.6, 0.2, 0.1"/></bsdf>',
        floor='<bsdf type="plastic"/>')
    add("roughplastic-beckmann",
        sphere='<bsdf type="roughplastic"><float name="alpha" value="0.2"/><boolean name="nonlinear" value="true"/>'
               '<rgb name="diffuse_reflectance" value="0.1, 0.3, 0.7"/></bsdf>')
    add("roughplastic-ggx",
        floor='<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf>')
    add("roughconductor-beckmann",
        sphere='<bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.15"/></bsdf>',
        floor='<bsdf type="roughconductor"><string name="material" value="Al"/><float name="alpha" value="0.3"/></bsdf>')
    add("roughconductor-textured",
        sphere='<bsdf type="roughconductor"><string name="material" value="Au"/><texture type="checkerboard" name="alpha">'
               '<float name="color0" value="0.05"/><float name="color1" value="0.4"/>'
               '<transform name="to_uv"><scale x="8" y="4"/></transform></texture></bsdf>',
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="roughconductor"><string name="distribution" value="ggx"/><string name="material" value="Al"/>'
              '<texture type="bitmap" name="alpha_u"><string name="filename" value="texture.png"/></texture>'
              '<texture type="bitmap" name="alpha_v"><string name="filename" value="texture.png"/></texture></bsdf></shape>')
    add("roughconductor-anisotropic",
        sphere='<bsdf type="roughconductor"><string name="material" value="Au"/>'
               '<float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.4"/></bsdf>',
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="roughconductor"><string name="distribution" value="ggx"/><string name="material" value="Al"/>'
              '<texture type="checkerboard" name="alpha_u"><float name="color0" value="0.2"/><float name="color1" value="0.5"/>'
              '<transform name="to_uv"><scale x="3" y="3"/></transform></texture>'
              '<float name="alpha_v" value="0.02"/></bsdf></shape>')
    add("roughdielectric-anisotropic",
        sphere='<bsdf type="roughdielectric"><string name="distribution" value="ggx"/>'
               '<float name="alpha_u" value="0.4"/><float name="alpha_v" value="0.03"/></bsdf>',
        floor='<bsdf type="diffuse"><ref name="reflectance" id="checks"/></bsdf>')
    add("roughdielectric-textured",
        sphere='<bsdf type="roughdielectric"><texture type="checkerboard" name="alpha">'
               '<float name="color0" value="0.01"/><float name="color1" value="0.7"/>'
               '<transform name="to_uv"><scale x="3" y="2"/></transform></texture></bsdf>')
    add("conductor-named", sphere='<bsdf type="conductor"><string name="material" value="Cu"/></bsdf>')
    add("roughdielectric-beckmann",
        sphere='<bsdf type="roughdielectric"><float name="alpha" value="0.2"/></bsdf>')
    add("thindielectric", sphere='<bsdf type="thindielectric"/>')
    add("mask", sphere='<bsdf type="mask"><float name="opacity" value="0.4"/>'
                       '<bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.1, 0.1"/></bsdf></bsdf>')
    add("spectra",
        sphere='<bsdf type="diffuse"><spectrum name="reflectance" value="400:0.04, 500:0.06, 550:0.3, 600:0.6, 700:0.64"/></bsdf>',
        light="""<shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.5"/><translate x="0.4" y="2.2" z="0.3"/></transform>
        <emitter type="area"><spectrum name="radiance" value="400:0, 500:8, 600:15.6, 700:18.4"/></emitter>
    </shape>
    <emitter type="constant"><spectrum name="radiance" value="0.2"/></emitter>""")
    add("integrator-direct", integrator='<integrator type="direct"/>')
    add("directional", light=AREA + """
    <emitter type="directional"><vector name="direction" x="-0.4" y="-1" z="-0.3"/><rgb name="irradiance" value="2, 1.8, 1.5"/></emitter>""")
    add("spot", light=AREA + """
    <emitter type="spot"><rgb name="intensity" value="6, 5, 4"/><float name="cutoff_angle" value="25"/>
        <transform name="to_world"><lookat origin="-1, 2, 1" target="0, 0, 0"/></transform>
    </emitter>""")
    # A point light above the sphere (by `position`), seen through a 35 mm lens (`focal_length`,
    # Mitsuba's field of view along the diagonal, in place of `fov`).
    add("point", light="""<emitter type="constant"><rgb name="radiance" value="0.05, 0.06, 0.08"/></emitter>
    <emitter type="point"><rgb name="intensity" value="3, 2.7, 2.4"/><point name="position" x="-0.6" y="1.8" z="0.9"/></emitter>""",
        sensor=PERSPECTIVE.replace('<float name="fov" value="40"/>', '<string name="focal_length" value="35mm"/>'))
    # A spot projecting the 16 x 12 texture down onto the floor and the sphere.
    add("spot-texture", light="""<emitter type="constant"><rgb name="radiance" value="0.05, 0.06, 0.08"/></emitter>
    <emitter type="spot"><rgb name="intensity" value="12, 11, 10"/><float name="cutoff_angle" value="32"/>
        <texture type="bitmap" name="texture"><string name="filename" value="texture.png"/></texture>
        <transform name="to_world"><lookat origin="0.3, 3, 1.4" target="0, 0, 0.3" up="0, 0, -1"/></transform>
    </emitter>""")
    # A projector casting the 16 x 12 texture (its aspect sets the frustum's) from the front left.
    add("projector", light="""<emitter type="constant"><rgb name="radiance" value="0.05, 0.06, 0.08"/></emitter>
    <emitter type="projector"><float name="fov" value="45"/><float name="scale" value="1.5"/>
        <texture type="bitmap" name="irradiance"><string name="filename" value="texture.png"/></texture>
        <transform name="to_world"><lookat origin="-1, 2.4, 2.2" target="0, 0.2, 0" up="0, 1, 0"/></transform>
    </emitter>""")
    add("disk", light="""<shape type="disk">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.4"/><translate x="0.4" y="2.2" z="0.3"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 11, 10"/></emitter>
    </shape>
    <shape type="disk">
        <transform name="to_world"><scale value="0.6"/><translate x="-0.8" y="0.8" z="-1.2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.3"/></bsdf>
    </shape>""")
    # An emitting tube along p0-p1 and a textured open tube (two-sided: its inside shows).
    add("cylinder", light="""<shape type="cylinder">
        <point name="p0" x="0.9" y="1.7" z="-0.4"/><point name="p1" x="-0.5" y="2.0" z="0.3"/>
        <float name="radius" value="0.12"/>
        <emitter type="area"><rgb name="radiance" value="9, 8, 7"/></emitter>
    </shape>
    <shape type="cylinder">
        <point name="p0" x="-0.9" y="0" z="-0.3"/><point name="p1" x="-0.7" y="1.0" z="-0.7"/>
        <float name="radius" value="0.3"/>
        <transform name="to_world"><rotate y="1" angle="20"/><translate x="0.1"/></transform>
        <bsdf type="twosided"><bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
            <rgb name="color0" value="0.85, 0.8, 0.7"/><rgb name="color1" value="0.05, 0.05, 0.1"/>
            </texture></bsdf></bsdf>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.15, 0.2, 0.25"/></emitter>""")
    add("integrator-plugin", mitsuba=scene("integrator-plugin", integrator='<integrator type="path"><integer name="max_depth" value="6"/></integrator>'),
        integrator='<integrator type="guided_path"><integer name="max_depth" value="6"/><string name="budget_type" value="spp"/></integrator>')
    add("bitmap",
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="texture.png"/></texture></bsdf></shape>',
        sphere='<bsdf type="roughplastic"><float name="alpha" value="0.3"/><texture type="bitmap" name="diffuse_reflectance">'
               '<string name="filename" value="texture.png"/><string name="filter_type" value="nearest"/>'
               '<string name="wrap_mode" value="mirror"/><transform name="to_uv"><scale x="3" y="2"/></transform></texture></bsdf>')
    add("checkerboard",
        floor='<bsdf type="diffuse"><ref name="reflectance" id="checks"/></bsdf>',
        sphere='<bsdf type="diffuse"><texture type="checkerboard" name="reflectance"><rgb name="color0" value="0.8, 0.2, 0.1"/>'
               '<rgb name="color1" value="0.1, 0.3, 0.8"/><transform name="to_uv"><scale x="8" y="4"/></transform></texture></bsdf>')
    add("mask-bitmap",
        sphere='<bsdf type="mask"><texture type="bitmap" name="opacity"><string name="filename" value="texture.png"/></texture>'
               '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.2"/></bsdf></bsdf>')
    add("serialized",
        floor='<shape type="serialized"><string name="filename" value="meshes.serialized"/>'
              '<integer name="shape_index" value="1"/><bsdf type="diffuse"><texture type="checkerboard" name="reflectance"/></bsdf></shape>'
              '<shape type="serialized"><string name="filename" value="meshes.serialized"/>'
              '<transform name="to_world"><scale value="0.8"/><translate x="-0.9" z="0.5"/></transform>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>')
    add("bumpmap",
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="bumpmap"><texture type="bitmap" name="height"><string name="filename" value="texture.png"/>'
              '<boolean name="raw" value="true"/></texture><float name="scale" value="0.3"/>'
              '<bsdf type="roughplastic"><float name="alpha" value="0.15"/></bsdf></bsdf></shape>')
    add("ply", sphere='<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.3, 0.2"/></bsdf>',
        floor=FLOOR.format(bsdf=DIFFUSE) + '<shape type="ply"><string name="filename" value="wedge.ply"/>'
              '<transform name="to_world"><scale value="0.9"/><translate x="0.8" z="0.6"/></transform>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.8"/></bsdf></shape>')
    add("envmap", light="""<emitter type="envmap">
        <string name="filename" value="sky.exr"/>
        <float name="scale" value="1.5"/>
        <transform name="to_world"><rotate y="1" angle="70"/></transform>
    </emitter>""", sphere='<bsdf type="roughconductor"><string name="material" value="Al"/><float name="alpha" value="0.1"/></bsdf>')
    # Mitsuba 3's sky is z-up: to_world turns it onto this y-up world.
    add("sunsky", light="""<emitter type="sunsky">
        <integer name="year" value="2021"/><integer name="month" value="4"/><integer name="day" value="20"/>
        <float name="hour" value="10.5"/><float name="latitude" value="48.1"/><float name="longitude" value="11.6"/>
        <float name="timezone" value="2"/><float name="turbidity" value="4"/><rgb name="albedo" value="0.2, 0.3, 0.4"/>
        <float name="sun_aperture" value="2"/>
        <transform name="to_world"><rotate x="1" angle="-90"/><rotate y="1" angle="30"/></transform>
    </emitter>""", sphere='<bsdf type="roughconductor"><string name="material" value="Al"/><float name="alpha" value="0.25"/></bsdf>')
    add("sunsky-complex", light="""<emitter type="sunsky">
        <vector name="sun_direction" x="-0.5" y="0.6" z="0.4"/><boolean name="complex_sun" value="true"/>
        <float name="sun_aperture" value="3"/><float name="sun_scale" value="0.8"/><float name="sky_scale" value="0.5"/>
        <float name="turbidity" value="6.5"/><float name="albedo" value="0.5"/>
        <transform name="to_world"><rotate x="1" angle="-90"/></transform>
    </emitter>""")
    add("blendbsdf",
        sphere='<bsdf type="blendbsdf"><float name="weight" value="0.35"/>'
               '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.7"/></bsdf>'
               '<bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.2"/></bsdf></bsdf>')
    add("blendbsdf-textured",
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="blendbsdf"><texture type="bitmap" name="weight"><string name="filename" value="texture.png"/></texture>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.3"/></bsdf>'
              '<bsdf type="roughplastic"><float name="alpha" value="0.1"/><rgb name="diffuse_reflectance" value="0.05, 0.1, 0.3"/></bsdf>'
              '</bsdf></shape>')
    add("normalmap",
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="normalmap"><texture type="bitmap" name="normalmap"><string name="filename" value="normals.png"/>'
              '<boolean name="raw" value="true"/></texture>'
              '<bsdf type="roughplastic"><float name="alpha" value="0.1"/></bsdf></bsdf></shape>')
    # A constant normal tilted towards +x on the floor (0 if ignored: the plain floor), and a
    # sphere whose roughness (a number) and tint (a vector) are raw constants.
    add("rawconstant",
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="normalmap"><texture type="rawconstant" name="normalmap"><vector name="value" value="0.75, 0.5, 0.85"/>'
              '</texture><bsdf type="roughplastic"><float name="alpha" value="0.1"/></bsdf></bsdf></shape>',
        sphere='<bsdf type="roughconductor"><string name="material" value="Au"/>'
               '<texture type="rawconstant" name="alpha"><float name="value" value="0.15"/></texture>'
               '<texture type="rawconstant" name="specular_reflectance"><vector name="value" value="0.9, 0.6, 0.3"/></texture></bsdf>')
    # Mesh attributes of PLY files: a floor grid whose vertex colours ramp along x and z (its
    # reflectance), and the wedge, whose faces' weights blend two diffuse BSDFs.
    add("mesh_attribute",
        floor='<shape type="ply"><string name="filename" value="attributes.ply"/>'
              '<bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/>'
              '<float name="scale" value="0.9"/></texture></bsdf></shape>'
              '<shape type="ply"><string name="filename" value="wedge-weights.ply"/>'
              '<transform name="to_world"><scale value="0.9"/><translate x="-0.9" z="0.5"/></transform>'
              '<bsdf type="blendbsdf"><texture type="mesh_attribute" name="weight"><string name="name" value="face_weight"/></texture>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.8, 0.2"/></bsdf>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.05, 0.1, 0.4"/></bsdf></bsdf></shape>')
    add("principled",
        sphere='<bsdf type="principled"><rgb name="base_color" value="0.8, 0.3, 0.2"/><float name="roughness" value="0.4"/>'
               '<float name="sheen" value="0.5"/><float name="sheen_tint" value="0.5"/><float name="clearcoat" value="0.7"/>'
               '<float name="clearcoat_gloss" value="0.3"/><float name="spec_tint" value="0.3"/><float name="flatness" value="0.3"/></bsdf>',
        floor='<bsdf type="principled"><rgb name="base_color" value="0.7, 0.6, 0.5"/><float name="metallic" value="0.6"/>'
              '<float name="roughness" value="0.35"/><float name="specular" value="0.7"/></bsdf>')
    add("principled-transmission",
        sphere='<bsdf type="principled"><rgb name="base_color" value="0.7, 0.9, 0.8"/><float name="spec_trans" value="0.8"/>'
               '<float name="roughness" value="0.3"/><float name="eta" value="1.45"/><float name="clearcoat" value="0.3"/></bsdf>')
    add("principled-textured",
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="principled"><texture type="bitmap" name="base_color"><string name="filename" value="texture.png"/></texture>'
              '<texture type="checkerboard" name="metallic"><rgb name="color0" value="0"/><rgb name="color1" value="1"/>'
              '<transform name="to_uv"><scale x="4" y="4"/></transform></texture><float name="roughness" value="0.3"/></bsdf></shape>')
    add("principled-anisotropic",
        sphere='<bsdf type="principled"><rgb name="base_color" value="0.9, 0.7, 0.4"/><float name="metallic" value="0.8"/>'
               '<float name="roughness" value="0.5"/><float name="anisotropic" value="0.9"/><float name="clearcoat" value="0.3"/></bsdf>',
        floor='<shape type="obj"><string name="filename" value="quad-uv.obj"/>'
              '<bsdf type="principled"><rgb name="base_color" value="0.8, 0.8, 0.8"/><float name="metallic" value="1"/>'
              '<float name="roughness" value="0.4"/><texture type="checkerboard" name="anisotropic">'
              '<float name="color0" value="0"/><float name="color1" value="1"/>'
              '<transform name="to_uv"><scale x="3" y="3"/></transform></texture></bsdf></shape>')
    # The sphere's centre is 3.2 from the camera: in focus at 2.2 it is blurred.
    add("sensor-thinlens", sensor="""<sensor type="thinlens">
        <float name="fov" value="40"/>
        <float name="aperture_radius" value="0.15"/>
        <float name="focus_distance" value="2.2"/>
        <transform name="to_world">
            <lookat origin="0, 1.6, 3" target="0, 0.4, 0" up="0, 1, 0"/>
        </transform>""")
    add("sensor-orthographic", sensor="""<sensor type="orthographic">
        <transform name="to_world">
            <scale value="1.4"/>
            <lookat origin="0.3, 1.6, 3" target="0, 0.4, 0" up="0, 1, 0"/>
        </transform>""")
    legacy = scene("legacy-0.5", version="0.5.0",
                   sphere='<bsdf type="roughconductor"><float name="alpha" value="0.2"/><string name="material" value="Cu"/>'
                          '<float name="extEta" value="1.0"/></bsdf>',
                   floor='<bsdf type="diffuse"><srgb name="diffuseReflectance" value="0.5, 0.6, 0.7"/></bsdf>',
                   integrator='<integrator type="path"><integer name="maxDepth" value="8"/><integer name="rrDepth" value="5"/></integrator>')
    legacy = (legacy.replace('name="to_world"', 'name="toWorld"').replace("<lookat", "<lookAt")
              .replace('name="sample_count"', 'name="sampleCount"'))
    twin = scene("legacy-0.5",
                 sphere='<bsdf type="roughconductor"><float name="alpha" value="0.2"/><string name="material" value="Cu"/></bsdf>',
                 floor='<bsdf type="diffuse"><rgb name="reflectance" value="%s"/></bsdf>'
                       % ", ".join(f"{srgb_to_linear(c):.6f}" for c in (0.5, 0.6, 0.7)),
                 integrator='<integrator type="path"><integer name="max_depth" value="8"/><integer name="rr_depth" value="5"/></integrator>')
    out.append(("legacy-0.5", legacy, twin))
    return out


QUAD_OBJ = """# A 4 x 4 floor quad at y = 0 facing +y, texture coordinates 0..2 (the image repeats).
v -2 0 2
v 2 0 2
v 2 0 -2
v -2 0 -2
vt 0 0
vt 2 0
vt 2 2
vt 0 2
vn 0 1 0
f 1/1/1 2/2/1 3/3/1 4/4/1
"""


def serialized_v4(meshes):
    """Mitsuba's serialized format, version 4 (what Mitsuba 0.x wrote), single precision:
    each mesh (positions, normals or None, uvs or None, triangles) zlib-compressed after its
    header, the table of offsets and the count at the end."""
    import struct
    import zlib
    out, offsets = b"", []
    for positions, normals, uvs, triangles in meshes:
        offsets.append(len(out))
        flags = 0x1000 | (0x1 if normals else 0) | (0x2 if uvs else 0)
        body = struct.pack("<I", flags) + b"mesh\0" + struct.pack("<QQ", len(positions), len(triangles))
        for rows in (positions, normals or [], uvs or []):
            for row in rows:
                body += struct.pack(f"<{len(row)}f", *row)
        for t in triangles:
            body += struct.pack("<3I", *t)
        out += struct.pack("<HH", 0x041C, 4) + zlib.compress(body)
    return out + b"".join(struct.pack("<Q", o) for o in offsets) + struct.pack("<I", len(meshes))


def ply_binary(mesh):
    """A binary little-endian PLY of (positions, normals, uvs, triangles); normals, uvs None."""
    positions, normals, uvs, triangles = mesh
    columns = (["nx", "ny", "nz"] if normals else []) + (["u", "v"] if uvs else [])
    rows = [
        (list(normals[i]) if normals else []) + (list(uvs[i]) if uvs else [])
        for i in range(len(positions))
    ]
    return ply_attributes(positions, triangles, columns, rows, [], [[]] * len(triangles))


def ply_attributes(positions, triangles, vertex_columns, vertex_rows, face_columns, face_rows):
    """A binary little-endian PLY with extra float properties per vertex and per face."""
    import struct
    head = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {len(positions)}\n"
    head += "".join(f"property float {p}\n" for p in ["x", "y", "z"] + vertex_columns)
    head += f"element face {len(triangles)}\nproperty list uchar int vertex_indices\n"
    head += "".join(f"property float {p}\n" for p in face_columns) + "end_header\n"
    body = b""
    for p, row in zip(positions, vertex_rows):
        body += struct.pack(f"<{3 + len(row)}f", *p, *row)
    for t, row in zip(triangles, face_rows):
        body += struct.pack("<B3i", 3, *t) + struct.pack(f"<{len(row)}f", *row)
    return head.encode() + body


def write_data(mi):
    """The mesh and the 16 x 12 sRGB image the textured scenes read."""
    import numpy as np
    (OUT / "quad-uv.obj").write_text(QUAD_OBJ)
    # Two meshes: a wedge (index 0) and the floor quad with normals and uvs (index 1).
    wedge = ([(-0.5, 0, -0.5), (0.5, 0, -0.5), (0, 0.8, -0.2), (0, 0, 0.4)], None, None,
             [(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)])
    floor = ([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)], [(0, 1, 0)] * 4,
             [(0, 0), (2, 0), (2, 2), (0, 2)], [(0, 1, 2), (2, 3, 0)])
    (OUT / "meshes.serialized").write_bytes(serialized_v4([wedge, floor]))
    (OUT / "wedge.ply").write_bytes(ply_binary(wedge))
    # A 4 x 4 floor of 4 x 4 cells, vertex colours ramping along x and z, and the wedge with
    # a weight per face.
    grid = [(-2 + i, 0, -2 + j) for j in range(5) for i in range(5)]
    cells = [(i, j) for j in range(4) for i in range(4)]
    tris = []
    for i, j in cells:
        a, b, c, d = (j + 1) * 5 + i, (j + 1) * 5 + i + 1, j * 5 + i + 1, j * 5 + i
        tris += [(a, b, c), (a, c, d)]
    colours = [(0.1 + 0.2 * (x + 2), 0.9 - 0.2 * (z + 2), 0.3) for x, _, z in grid]
    (OUT / "attributes.ply").write_bytes(ply_attributes(
        grid, tris, ["r", "g", "b"], colours, ["weight_0"], [(0.5,)] * len(tris)))
    (OUT / "wedge-weights.ply").write_bytes(ply_attributes(
        wedge[0], wedge[3], [], [()] * 4, ["weight_0"], [(0.0,), (1.0,), (0.15,), (0.85,)]))
    y, x = np.mgrid[0:12, 0:16]
    img = np.stack([(x * 16) % 256, (y * 21) % 256, ((x + y) % 2) * 200 + 30], axis=-1).astype(np.uint8)
    mi.Bitmap(img).write(str(OUT / "texture.png"))
    # A 16 x 16 normal map (read raw): normals tilted by two waves, encoded as (n + 1) / 2.
    v16, u16 = np.mgrid[0:16, 0:16]
    nx = 0.45 * np.sin(2 * np.pi * u16 / 16)
    ny = 0.35 * np.cos(2 * np.pi * v16 / 8)
    nz = np.sqrt(1 - nx * nx - ny * ny)
    normals = np.stack([nx, ny, nz], axis=-1) * 0.5 + 0.5
    mi.Bitmap(np.round(normals * 255).astype(np.uint8)).write(str(OUT / "normals.png"))
    # A 32 x 16 sky: a blue gradient, a bright sun and a dark ground.
    v, u = (np.mgrid[0:16, 0:32] + 0.5) / np.array([16, 32])[:, None, None]
    sky = np.stack([0.3 + 0.4 * v, 0.4 + 0.3 * v, 0.9 - 0.2 * v], axis=-1) * (v < 0.5)[..., None]
    sky += 0.1 * (v >= 0.5)[..., None]
    sky[3, 21] = [60.0, 55.0, 45.0]
    mi.Bitmap(sky.astype(np.float32)).write(str(OUT / "sky.exr"))


def srgb_to_linear(c):
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=4096, help="samples per pixel per seed")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--only", nargs="*", help="feature names to render (default: all)")
    args = ap.parse_args()
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    OUT.mkdir(parents=True, exist_ok=True)
    write_data(mi)
    means_path = OUT / "mitsuba-means.json"
    means = json.loads(means_path.read_text()) if means_path.exists() else {}
    means = {k: v for k, v in means.items() if "quadrants" in v}
    for name, ours, theirs in features():
        (OUT / f"{name}.xml").write_text(ours)
        if args.only and name not in args.only:
            continue
        with tempfile.NamedTemporaryFile("w", suffix=".xml", dir=OUT, delete=False) as f:
            f.write(theirs or ours)
        sc = mi.load_file(f.name, spp=args.spp)
        Path(f.name).unlink()
        import numpy as np
        values = []
        for seed in range(args.seeds):
            img = np.asarray(mi.TensorXf(mi.render(sc, seed=seed + 1, spp=args.spp)))[..., :3]
            h, w = img.shape[0] // 2, img.shape[1] // 2
            quads = [img[:h, :w], img[:h, w:], img[h:, :w], img[h:, w:]]
            values.append([float(img.mean())] + [float(q.mean()) for q in quads])
        values = np.array(values)
        m = values.mean(axis=0)
        se = values.std(axis=0, ddof=1) / math.sqrt(len(values))
        means[name] = {"mean": m[0], "std_err": se[0], "quadrants": list(m[1:]),
                       "quadrant_std_errs": list(se[1:]), "spp": args.spp * args.seeds,
                       "mitsuba": mi.__version__}
        print(f"{name:28s} {m[0]:.6f} ± {se[0]:.6f}", flush=True)
    means_path.write_text(json.dumps(means, indent=1, sort_keys=True) + "\n")
    print(f"wrote {means_path}")


if __name__ == "__main__":
    main()
