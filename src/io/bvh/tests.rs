use super::*;
use alloc::string::String;

const SMALL: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Spine
  {
    OFFSET 0 2 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 0 3 0
    }
  }
  JOINT Leg
  {
    OFFSET 1 -1 0
    CHANNELS 4 Yrotation Xposition Xrotation Zrotation
    End Site
    {
      OFFSET 0 -4 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.05
1 2 3 0 0 0 90 0 0 0 0 0 0
1 2 3 10 20 30 40 50 60 70 0.5 80 90
";

fn close(a: Quat, b: Quat) -> bool {
    a.dot(b).abs() > 1.0 - 1e-6
}

#[test]
fn bvh_reads_hierarchy_channels_and_frames() {
    let clip = parse(SMALL).unwrap();
    assert_eq!(clip.joints().len(), 3);
    assert_eq!(clip.n_frames(), 2);
    assert!((clip.frame_time() - 0.05).abs() < 1e-7);
    assert_eq!(clip.joints()[2].parent, Some(0));
    assert_eq!(clip.joints()[1].end_site, Some([0.0, 3.0, 0.0]));
    let d = f32::to_radians;
    // Frame 0: spine turned 90 degrees about x; root at (1, 2, 3).
    assert!(close(clip.rotations(0)[1], Quat::from_rotation_x(d(90.0))));
    assert_eq!(clip.translations(0)[0], Vec3::new(1.0, 2.0, 3.0));
    // Frame 1: channels compose in the listed order, whatever it is.
    let r = clip.rotations(1);
    let root = Quat::from_rotation_z(d(10.0)) * Quat::from_rotation_y(d(20.0)) * Quat::from_rotation_x(d(30.0));
    assert!(close(r[0], root));
    let spine = Quat::from_rotation_x(d(40.0)) * Quat::from_rotation_z(d(50.0)) * Quat::from_rotation_y(d(60.0));
    assert!(close(r[1], spine));
    let leg = Quat::from_rotation_y(d(70.0)) * Quat::from_rotation_x(d(80.0)) * Quat::from_rotation_z(d(90.0));
    assert!(close(r[2], leg));
    // A position channel on a non-root joint adds to its offset.
    assert_eq!(clip.translations(1)[2], Vec3::new(1.5, -1.0, 0.0));
    // World positions: spine at root + R_root * (0, 2, 0).
    let (mut rot, mut pos) = ([Quat::IDENTITY; 3], [Vec3::ZERO; 3]);
    clip.world(1, &mut rot, &mut pos);
    assert!((pos[1] - (Vec3::new(1.0, 2.0, 3.0) + root * Vec3::new(0.0, 2.0, 0.0))).length() < 1e-5);
}

fn line_of(text: &str) -> usize {
    match parse(text) {
        Err(Error::Parse { format: "bvh", line, .. }) => line,
        other => panic!("expected a bvh parse error, got {other:?}"),
    }
}

#[test]
fn bvh_errors_name_the_line() {
    let edit = |from: &str, to: &str| -> String {
        assert!(SMALL.contains(from), "{from}");
        SMALL.replacen(from, to, 1)
    };
    // Missing HIERARCHY keyword.
    assert_eq!(line_of(&edit("HIERARCHY", "HIERARCH")), 1);
    // Unknown channel.
    assert_eq!(line_of(&edit("Xrotation Zrotation Yrotation", "Xrotation Wrotation Yrotation")), 9);
    // Bad number in an offset.
    assert_eq!(line_of(&edit("OFFSET 0 2 0", "OFFSET 0 two 0")), 8);
    // Missing closing brace: the root swallows MOTION's position, reported at the end.
    let unbalanced = edit("    }\n  }\n  JOINT Leg", "    }\n  JOINT Leg");
    assert!(line_of(&unbalanced) >= 20);
    // Channel count larger than listed channels runs into the next keyword.
    assert_eq!(line_of(&edit("CHANNELS 3 Xrotation", "CHANNELS 4 Xrotation")), 10);
    // Wrong number of values in a frame line.
    assert_eq!(line_of(&edit("1 2 3 0 0 0 90 0 0 0 0 0 0", "1 2 3 0 0 0 90 0 0 0 0 0")), 28);
    // A bad value in a frame line.
    assert_eq!(line_of(&edit("70 0.5 80 90", "70 x 80 90")), 29);
    // Fewer frames than declared.
    assert_eq!(line_of(&edit("Frames: 2", "Frames: 3")), 30);
    // More frames than declared.
    assert_eq!(line_of(&edit("Frames: 2", "Frames: 1")), 29);
    // Frame time not positive, or not a number.
    assert_eq!(line_of(&edit("Frame Time: 0.05", "Frame Time: 0")), 27);
    assert_eq!(line_of(&edit("Frame Time: 0.05", "Frame Time: fast")), 27);
    assert_eq!(line_of(&edit("Frame Time: 0.05", "Frametime 0.05")), 27);
    // Bad frame count.
    assert_eq!(line_of(&edit("Frames: 2", "Frames: -2")), 26);
    // No MOTION section at all.
    assert!(line_of(&edit("MOTION", "MOTIONS")) > 0);
    // A joint without a name.
    assert_eq!(line_of(&edit("JOINT Leg", "JOINT")), 16);
    // Garbage where a joint, end site or brace belongs.
    assert_eq!(line_of(&edit("  JOINT Leg", "  BONE Leg")), 15);
}

#[test]
fn bvh_resamples_to_30_hz() {
    let clip = parse(SMALL).unwrap();
    // 0.05 s between the two frames: 30 Hz gives frames at 0 and 1/30 s.
    let r = clip.resample(30.0).unwrap();
    assert_eq!(r.n_frames(), 2);
    let a = (1.0 / 30.0) / 0.05;
    let expect = clip.rotations(0)[1].slerp(clip.rotations(1)[1], a);
    assert!(close(r.rotations(1)[1], expect));
    assert!((r.translations(1)[2].x - (1.0 + 0.5 * a)).abs() < 1e-5);
    assert!(close(r.rotations(0)[2], clip.rotations(0)[2]));
}

#[test]
fn bvh_frame_counts_beyond_the_file_or_the_sample_bound_are_refused_unallocated() {
    // 10^8 frames declared in a file of two: refused without reserving room for them.
    let e = parse(&SMALL.replacen("Frames: 2", "Frames: 100000000", 1)).unwrap_err();
    assert!(e.to_string().contains("100000000 frames declared, 2 found"), "{e}");
    // 5,000 joints (siblings, one with channels) over 14,000 frames: 7 * 10^7 joint samples,
    // beyond MAX_MOTION_SAMPLES, although the file is under 250 kB.
    let mut text = String::from("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 1 Xrotation\n");
    for j in 0..4999 {
        text.push_str(&alloc::format!("JOINT j{j}\n{{\nOFFSET 0 0 0\nCHANNELS 0\n}}\n"));
    }
    text.push_str("}\nMOTION\nFrames: 14000\nFrame Time: 0.1\n");
    for _ in 0..14000 {
        text.push_str("0\n");
    }
    let e = parse(&text).unwrap_err();
    assert!(matches!(e, Error::CapacityExceeded { needed: 70_000_000, .. }), "{e}");
}

#[test]
fn bvh_with_a_huge_frame_time_is_refused_when_resampled_not_allocated() {
    // Found by the bvh fuzz target: three frames 6,066,666 s apart, resampled at 30 Hz, asked
    // for 5.5 * 10^8 frames (5.8 GB) before this was bounded.
    let text = SMALL.replacen("Frame Time: 0.05", "Frame Time: 06066666", 1);
    let clip = parse(&text).unwrap();
    let e = clip.resample(30.0).unwrap_err();
    assert!(matches!(e, Error::CapacityExceeded { capacity: crate::limits::MAX_MOTION_SAMPLES, .. }), "{e}");
    assert!(parse(SMALL).unwrap().resample(30.0).is_ok());
    // Also found by it: 606,666 s between frames, 3.6 * 10^7 frames at 30 Hz (1 GB, a minute
    // to fill under the sanitizer) while MAX_MOTION_SAMPLES was 2^26.
    let text = SMALL.replacen("Frame Time: 0.05", "Frame Time: 0606666", 1);
    assert!(matches!(parse(&text).unwrap().resample(30.0), Err(Error::CapacityExceeded { .. })));
}
