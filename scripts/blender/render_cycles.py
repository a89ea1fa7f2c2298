"""Renders a Blender smoke/fire .blend with Cycles (CPU) under a nimbus command's camera and sun.

    blender -b fire.blend -t 1 --python-exit-code 1 -P scripts/blender/render_cycles.py -- \
        --eye X,Y,Z --look-at X,Y,Z [--up 0,0,1] [--fov 40] --width W --height H \
        [--sun dir=X,Y,Z,irradiance=E | --no-sun] [--samples 64] [--volume-bounces 8] \
        [--frame F] [--no-emission] [--density D] [--color C] [--seed 0] -o OUT.exr

The scene's own material is left as it is (make_smoke.py --fire gives Quick Smoke's fire
material: Principled Volume, Density 5 on the `density` attribute, Color 0.5, Absorption Color
black, Anisotropy 0, Blackbody Intensity 1, Temperature 1000 K on the `temperature`
attribute); `--no-emission` sets its Blackbody Intensity to 0 (the sun-lit smoke alone),
`--density D` its Density (a tiny one leaves emission unattenuated), `--color C` its Color.
Everything else is set so that the image means what a nimbus EXR means:

- Camera: nimbus's pinhole (design.md section 4): forward = look-at - eye, image right =
  cross(forward, up), horizontal field of view `--fov` degrees. A Blender camera looks along
  its local -Z with +Y up and +X right, so its world matrix has columns (right, true up,
  -forward, eye); the lens is 18 mm / tan(fov / 2) on a 36 mm sensor fitted horizontally, so
  the horizontal angle is the fov at any aspect. The scene's resolution is W x H at 100%.
- Sun: nimbus's `dir` is where the light travels; a Blender Sun shines along its local -Z, so
  its -Z is set to dir. Cycles' Sun Strength is irradiance in W/m^2 perpendicular to the
  light (the disc's radiance is strength / its solid angle), the same quantity as nimbus's
  `irradiance` E, so Strength = E (an RGB E becomes colour E / max(E) at Strength max(E)).
  Its angle is set to 0 (Blender's default is 0.526 degrees), a point at infinity as
  nimbus's sun. For a volume this gives in-scattered radiance sigma_s * phase * E * T, the
  same single-scattering integral nimbus computes (Cycles' volume scattering closure weight is
  sigma_s = colour * density, its Henyey-Greenstein phase is normalised over the sphere).
- World: black, strength 0, so only the sun and the fire light the smoke (nimbus's background
  is black by default).
- Film: box pixel filter 1 px wide (nimbus's pixel is the mean over its area), no adaptive
  sampling, no denoising, no clamping, fixed seed; the EXR is float32 RGBA and linear (an EXR
  never goes through the view transform; it is set to Standard anyway).
- Light paths: `--volume-bounces` (default 8; Cycles' own default is 0, single scattering
  only, where nimbus's chain has every order) and max bounces enough for it. Volume step rate
  and max steps stay at Cycles' defaults (1 and 1024) unless `--step-rate` is given.
- Frame: `--frame` (default the scene's frame_end, the frame make_smoke.py copies to fire.vdb).
"""

import argparse
import math
import sys
import time

import bpy
from mathutils import Matrix, Vector


def vec3(text):
    v = [float(x) for x in text.split(",")]
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z, got {text!r}")
    return Vector(v)


def sun_spec(text):
    """nimbus's --sun syntax: dir=X,Y,Z,irradiance=E or irradiance=R,G,B."""
    out, key = {}, None
    for part in text.split(","):
        if "=" in part:
            key, part = part.split("=", 1)
            out[key] = []
        if key is None:
            raise argparse.ArgumentTypeError(f"bad sun {text!r}")
        out[key].append(float(part))
    d = out.get("dir", [0.0, 0.0, -1.0])
    e = out.get("irradiance", [1.0])
    if len(d) != 3 or len(e) not in (1, 3):
        raise argparse.ArgumentTypeError(f"bad sun {text!r}")
    return Vector(d), (e * 3 if len(e) == 1 else e)


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="render_cycles.py", description=__doc__.split("\n")[0])
    p.add_argument("--eye", type=vec3, required=True)
    p.add_argument("--look-at", type=vec3, required=True)
    p.add_argument("--up", type=vec3, default=Vector((0.0, 0.0, 1.0)))
    p.add_argument("--fov", type=float, default=40.0, help="horizontal, degrees")
    p.add_argument("--width", type=int, default=960)
    p.add_argument("--height", type=int, default=540)
    p.add_argument("--sun", type=sun_spec, default=None)
    p.add_argument("--no-sun", action="store_true")
    p.add_argument("--no-emission", action="store_true")
    p.add_argument("--density", type=float, default=None,
                   help="replace the material's Density (e.g. 0.001: emission without attenuation)")
    p.add_argument("--samples", type=int, default=64)
    p.add_argument("--volume-bounces", type=int, default=8)
    p.add_argument("--step-rate", type=float, default=None)
    p.add_argument("--color", type=float, default=None,
                   help="replace the material's Color (grey; 0 with the black Absorption Color: "
                        "a pure absorber)")
    p.add_argument("--frame", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", required=True)
    return p.parse_args(argv)


def camera_matrix(eye, look_at, up):
    f = (look_at - eye).normalized()
    r = f.cross(up).normalized()
    u = r.cross(f)
    m = Matrix.Identity(4)
    for row in range(3):
        m[row][0], m[row][1], m[row][2], m[row][3] = r[row], u[row], -f[row], eye[row]
    return m


def main():
    args = parse_args()
    scene = bpy.context.scene
    scene.frame_set(args.frame if args.frame is not None else scene.frame_end)

    cam_data = bpy.data.cameras.new("nimbus camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_data.lens = 18.0 / math.tan(math.radians(args.fov) / 2.0)
    cam_data.clip_start, cam_data.clip_end = 1e-3, 1e4
    cam = bpy.data.objects.new("nimbus camera", cam_data)
    scene.collection.objects.link(cam)
    cam.matrix_world = camera_matrix(args.eye, args.look_at, args.up)
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = args.width, args.height
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0

    # Only our sun: other lights in the file are hidden from the render.
    for ob in scene.objects:
        if ob.type == "LIGHT":
            ob.hide_render = True
    if not args.no_sun:
        d, e = args.sun if args.sun else (Vector((0.0, 0.0, -1.0)), [1.0] * 3)
        strength = max(e)
        sun_data = bpy.data.lights.new("nimbus sun", type="SUN")
        sun_data.energy = strength
        sun_data.color = [c / strength for c in e] if strength > 0 else (1.0, 1.0, 1.0)
        sun_data.angle = 0.0
        sun = bpy.data.objects.new("nimbus sun", sun_data)
        scene.collection.objects.link(sun)
        # Light travels along the object's -Z.
        sun.rotation_euler = d.normalized().to_track_quat("-Z", "Y").to_euler()

    world = bpy.data.worlds.new("black")
    world.use_nodes = False
    world.color = (0.0, 0.0, 0.0)
    scene.world = world

    volumes = []
    for mat in bpy.data.materials:
        if not mat.use_nodes:
            continue
        for node in mat.node_tree.nodes:
            if node.bl_idname == "ShaderNodeVolumePrincipled":
                if args.no_emission:
                    node.inputs["Blackbody Intensity"].default_value = 0.0
                if args.density is not None:
                    node.inputs["Density"].default_value = args.density
                if args.color is not None:
                    node.inputs["Color"].default_value = (args.color,) * 3 + (1.0,)
                volumes.append((mat.name, node))

    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = args.samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = args.seed
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.volume_bounces = args.volume_bounces
    c.max_bounces = max(c.max_bounces, args.volume_bounces)
    if args.step_rate is not None:
        c.volume_step_rate = args.step_rate
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    im = scene.render.image_settings
    im.file_format = "OPEN_EXR"
    im.color_mode = "RGBA"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.render.filepath = args.output
    scene.render.use_file_extension = False

    for name, node in volumes:
        ins = node.inputs
        print(f"render_cycles: material {name!r}: Principled Volume density "
              f"{ins['Density'].default_value} x '{node.inputs['Density Attribute'].default_value}', "
              f"colour {tuple(ins['Color'].default_value)[:3]}, anisotropy "
              f"{ins['Anisotropy'].default_value}, blackbody {ins['Blackbody Intensity'].default_value}"
              f" at {ins['Temperature'].default_value} K x "
              f"'{ins['Temperature Attribute'].default_value}'", flush=True)
    print(f"render_cycles: frame {scene.frame_current}, {args.width}x{args.height}, "
          f"{args.samples} spp, volume bounces {c.volume_bounces}, step rate "
          f"{c.volume_step_rate}, lens {cam_data.lens:.4f} mm / 36 mm horizontal "
          f"(fov {args.fov}), sun {'none' if args.no_sun else (tuple(args.sun[0]) if args.sun else (0, 0, -1), args.sun[1] if args.sun else 1)}, "
          f"threads {scene.render.threads}", flush=True)
    t0 = time.time()
    bpy.ops.render.render(write_still=True)
    print(f"render_cycles: {args.output} in {time.time() - t0:.1f} s", flush=True)


if __name__ == "__main__":
    main()
