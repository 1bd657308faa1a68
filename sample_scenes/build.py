# SPDX-License-Identifier: GPL-3.0-or-later
"""Build the sample scenes of sample_scenes/ from nothing but Blender, the extension and the CMU clips.

    FBA_BPY=4.2 .ci/with-bpy python sample_scenes/build.py            # every sample, into sample_scenes/
    FBA_BPY=4.2 .ci/with-bpy python sample_scenes/build.py --only reach_near_far --out /tmp/samples

Build with the oldest supported Blender (4.2) so every supported version opens the files. Every number below
is fixed (no randomness, no dependence on the solver's output), so a build makes the same scenes each time.

Samples (paper figures in brackets; README.md next to this file says how to run them):

* reach_near_far.blend [Fig. 10]: a Rigify basic metarig whose right-hand target moves from the hand's rest
  place to a near point (the arm alone reaches it: the trunk keeps its pose), then to a far point (the trunk
  must bend to help); feet pinned where they stand.
* arm_obstacles.blend [Fig. 9]: the right hand reaches in front of the chest while two small boxes sit on the
  arm's free path (the green one sinks onto it over the frames): the elbow has to give way.
* captured_pose.blend [Fig. 11-12]: a CMU performer standing (clip 02_06, a few frames of it) with four
  targets taken from the wrists and ankles of a captured bent-over pose of the same clip; the captured pose
  itself is kept as the armature 'Captured' to compare against.
* retarget_cmu.blend [Fig. 13]: the same clip's bend-and-pick-up (2 s at 30 fps) on 'Source', a ball where its
  right hand picks, and two mappable copies of its skeleton to retarget onto: 'Large' (bones 1.2x) and 'Small'
  (0.85x), without motion.
"""

import argparse
import math
import os
from pathlib import Path
import sys
import tempfile

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402  (first: it puts Blender's own modules, addon_utils among them, on the path)
import addon_utils  # noqa: E402

import fullbody_adjust  # noqa: E402
from fullbody_adjust.bridge.rig import mapping, targets  # noqa: E402

MOCAP = Path(os.environ.get("FBA_MOCAP_DIR", REPO / "tests" / "data" / "mocap"))
PICKUP_CLIP = "cmu_02_06_pickup_f0-1349.bvh"
CMU_SCALE = 0.056444  # metres per CMU BVH unit (mocap/README.md)
CMU_CREDIT = ("The data used in this project was obtained from mocap.cs.cmu.edu. The database was created with "
              "funding from NSF EIA-0196217. BVH conversion by Bruce Hahne (cgspeed).")

# Clip 02_06 (120 fps, frame index 0 = the converter's T-pose): standing still around 30-74, bent over with
# both hands lowest around 150 (first pick-up), arm lifted by 300.
STANDING_FRAMES = range(30, 75, 4)  # 12 frames at 30 fps
CAPTURED_FRAME = 150
PICKUP_FRAMES = range(66, 306, 4)  # 60 frames at 30 fps: bend, pick, rise, lift the arm
CLIP_STEP = 4  # 120 fps -> 30 fps

TARGET_SIZE = 0.06


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", choices=sorted(SAMPLES), help="build only this sample")
    parser.add_argument("--out", type=Path, default=HERE, help="folder for the .blend files (default: here)")
    args = parser.parse_args(argv)
    if bpy.app.version[:2] != (4, 2):
        print(f"build.py: note: building with Blender {bpy.app.version_string}; build with 4.2 "
              f"(FBA_BPY=4.2) so every supported version opens the files", file=sys.stderr)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups of earlier builds
    fullbody_adjust.register()
    for module in ("rigify", "io_anim_bvh"):
        addon_utils.enable(module, default_set=True)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.only or sorted(SAMPLES):
        bpy.ops.wm.read_homefile(use_empty=True)
        SAMPLES[name]()
        path = args.out / f"{name}.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)
        print(f"build.py: wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")


# --- the samples -------------------------------------------------------------------------------------------------

def reach_near_far():
    scene = _scene(frame_end=48, fps=24)
    character = _metarig("Character")
    _collection("Obstacles")  # none: the target is reached in open space
    character.fullbody_adjust.obstacles = bpy.data.collections["Obstacles"]
    rest_hand = _bone_head(character, "hand.R")
    made = targets.create_targets(scene, character, {
        "hand.R": rest_hand,
        "foot.L": _bone_head(character, "foot.L"),
        "foot.R": _bone_head(character, "foot.R"),
    }, TARGET_SIZE)
    near = (-0.28, -0.35, 1.22)  # within the arm's reach from the chest: only the arm moves
    far = (-0.30, -0.60, 0.60)  # beyond it: the trunk bends to help
    _key_locations(made["hand.R"], {1: rest_hand, 20: near, 28: near, 48: far})
    _select(character)


def arm_obstacles():
    scene = _scene(frame_end=24, fps=24)
    character = _metarig("Character")
    obstacles = _collection("Obstacles")
    character.fullbody_adjust.obstacles = obstacles
    targets.create_targets(scene, character, {
        "hand.R": (-0.22, -0.42, 1.12),
        "foot.L": _bone_head(character, "foot.L"),
        "foot.R": _bone_head(character, "foot.R"),
    }, TARGET_SIZE)
    # Blue touches the forearm of the unobstructed reach; Green sinks onto the upper arm over the frames. Both
    # push the elbow off its free path.
    _box("Blue", obstacles, centre=(-0.19, -0.33, 1.21), size=(0.06, 0.06, 0.06), colour=(0.1, 0.3, 0.9, 1.0))
    green = _box("Green", obstacles, centre=(-0.21, -0.14, 1.56), size=(0.05, 0.05, 0.05),
                 colour=(0.1, 0.7, 0.2, 1.0))
    _key_locations(green, {1: (-0.21, -0.14, 1.56), 24: (-0.21, -0.14, 1.44)})
    _select(character)


def captured_pose():
    _scene(frame_end=len(STANDING_FRAMES), fps=30)
    actor = _import_bvh("Actor", STANDING_FRAMES)
    captured = _import_bvh("Captured", [CAPTURED_FRAME])
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, len(STANDING_FRAMES)
    scene.frame_set(1)
    bone_map = mapping.ensure_map(captured)
    goals = {effector: _bone_head(captured, bone_map.bones(effector)[-1])
             for effector in ("hand.L", "hand.R", "foot.L", "foot.R")}
    targets.create_targets(scene, actor, goals, TARGET_SIZE)
    mapping.ensure_map(actor)
    _note("captured_pose", f"'Actor' stands (clip 02_06 frames {STANDING_FRAMES.start}-{STANDING_FRAMES[-1]}); "
                           f"its four targets are the wrists and ankles of 'Captured' (frame {CAPTURED_FRAME}).")
    _select(actor)


def retarget_cmu():
    _scene(frame_end=len(PICKUP_FRAMES), fps=30)
    source = _import_bvh("Source", PICKUP_FRAMES)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, len(PICKUP_FRAMES)
    bone_map = mapping.ensure_map(source)
    hand = bone_map.bones("hand.R")[-1]
    # The ball sits where the right wrist is lowest: where the source picks it up.
    lowest = min(range(1, len(PICKUP_FRAMES) + 1), key=lambda f: _bone_head(source, hand, frame=f)[2])
    ball_at = _bone_head(source, hand, frame=lowest)
    scene.frame_set(1)
    obstacles = _collection("Obstacles")  # empty: the ball is to be reached, not avoided
    _ball("Ball", ball_at, radius=0.05, colour=(0.9, 0.1, 0.1, 1.0))
    for name, factor in (("Large", 1.2), ("Small", 0.85)):
        copy = _scaled_copy(source, name, factor)
        copy.fullbody_adjust.obstacles = obstacles
        mapping.ensure_map(copy)
    _note("retarget_cmu", f"'Source' picks the ball up at frame {lowest} (clip 02_06 frames "
                          f"{PICKUP_FRAMES.start}-{PICKUP_FRAMES[-1]} at 30 fps). 'Large' (1.2x) and 'Small' "
                          f"(0.85x) are copies of its skeleton without motion, to retarget onto.")
    _select(source)


SAMPLES = {
    "reach_near_far": reach_near_far,
    "arm_obstacles": arm_obstacles,
    "captured_pose": captured_pose,
    "retarget_cmu": retarget_cmu,
}


# --- helpers -----------------------------------------------------------------------------------------------------

def _scene(frame_end, fps):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frame_end
    scene.render.fps = fps
    scene.frame_set(1)
    return scene


def _metarig(name):
    bpy.ops.object.armature_basic_human_metarig_add()
    obj = bpy.context.active_object
    obj.name = obj.data.name = name
    mapping.ensure_map(obj)
    return obj


def _bone_head(obj, bone, frame=None):
    if frame is not None:
        bpy.context.scene.frame_set(frame)
    return tuple(obj.matrix_world @ obj.pose.bones[bone].head)


def _key_locations(obj, by_frame):
    for frame, location in sorted(by_frame.items()):
        obj.location = location
        obj.keyframe_insert("location", frame=frame)
    bpy.context.scene.frame_set(1)


def _collection(name):
    collection = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(collection)
    return collection


def _material(name, colour):
    material = bpy.data.materials.new(name)
    material.diffuse_color = colour
    return material


def _box(name, collection, centre, size, colour):
    mesh = bpy.data.meshes.new(name)
    hx, hy, hz = (s / 2.0 for s in size)
    corners = [(x, y, z) for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.from_pydata(corners, [], faces)
    mesh.materials.append(_material(name, colour))
    obj = bpy.data.objects.new(name, mesh)
    obj.location = centre
    collection.objects.link(obj)
    return obj


def _ball(name, centre, radius, colour, rings=8, segments=12):
    mesh = bpy.data.meshes.new(name)
    verts = [(0.0, 0.0, radius), (0.0, 0.0, -radius)]
    for i in range(1, rings):
        theta = math.pi * i / rings
        for j in range(segments):
            phi = 2.0 * math.pi * j / segments
            verts.append((radius * math.sin(theta) * math.cos(phi), radius * math.sin(theta) * math.sin(phi),
                          radius * math.cos(theta)))
    ring = lambda i, j: 2 + (i - 1) * segments + (j % segments)  # noqa: E731
    faces = [(0, ring(1, j), ring(1, j + 1)) for j in range(segments)]
    faces += [(ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1))
              for i in range(1, rings - 1) for j in range(segments)]
    faces += [(1, ring(rings - 1, j + 1), ring(rings - 1, j)) for j in range(segments)]
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(_material(name, colour))
    obj = bpy.data.objects.new(name, mesh)
    obj.location = centre
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _import_bvh(name, frames):
    """Import the pick-up clip's ``frames`` (0-based BVH frame indices, evenly spaced) as armature ``name``."""
    frames = list(frames)
    step = frames[1] - frames[0] if len(frames) > 1 else 1
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{name}.bvh"
        path.write_text(_bvh_excerpt((MOCAP / PICKUP_CLIP).read_text(), frames, step))
        bpy.ops.import_anim.bvh(filepath=str(path), global_scale=CMU_SCALE, frame_start=1,
                                update_scene_fps=False, update_scene_duration=False)
    obj = bpy.context.active_object
    obj.name = obj.data.name = name
    obj.animation_data.action.name = f"{name}Motion"
    return obj


def _bvh_excerpt(text, frames, step):
    """The BVH ``text`` with only the motion lines ``frames`` (0-based), the frame time scaled by ``step``."""
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    frame_time = float(lines[1].split(":")[1])
    rows = lines[2:]
    kept = [rows[f] for f in frames]
    return (f"{head}MOTION\nFrames: {len(kept)}\nFrame Time: {frame_time * step:.7f}\n" + "\n".join(kept) + "\n")


def _scaled_copy(source, name, factor):
    """A copy of armature ``source`` with every bone ``factor`` times as long (rest pose scaled about the
    object's origin), without animation."""
    obj = source.copy()
    obj.data = source.data.copy()
    obj.name = obj.data.name = name
    obj.animation_data_clear()
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    bones = obj.data.edit_bones
    # Read every end first: a connected bone's head is its parent's tail, so scaling in place would scale twice.
    ends = [(bone.head * factor, bone.tail * factor) for bone in bones]
    for bone, (head, tail) in zip(bones, ends):
        bone.head, bone.tail = head, tail
    bpy.ops.object.mode_set(mode='OBJECT')
    for pose_bone in obj.pose.bones:
        pose_bone.location = (0.0, 0.0, 0.0)
        pose_bone.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        pose_bone.rotation_euler = (0.0, 0.0, 0.0)
    return obj


def _note(name, text):
    """A text block in the file saying what the scene is and crediting the motion data."""
    block = bpy.data.texts.new(f"{name}_README")
    block.write(f"{text}\n\n{CMU_CREDIT}\n")


def _select(obj):
    for other in bpy.context.scene.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # skip the bpy module's unreliable teardown (tests/conftest.py)
