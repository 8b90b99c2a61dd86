use super::*;
use std::vec;

fn parse_err(text: &str) -> (usize, String) {
    match Obj::parse(text) {
        Err(Error::Parse { format: "obj", line, message }) => (line, message),
        other => panic!("expected a parse error for {text:?}, got {other:?}"),
    }
}

#[test]
fn obj_reads_every_corner_form() {
    let text = "# a quad and a triangle\n\
                v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1 1.0\n\
                vt 0 0\nvt 1 0\nvt 1 1\n\
                vn 0 0 1\n\
                f 1 2 3 4\n\
                f 1/1 2/2 5/3\n\
                f 1//1 2//1 5//1\n\
                f 1/1/1 2/2/1 5/3/1\n\
                f 1 2/2 5//1\n";
    let obj = Obj::parse(text).unwrap();
    assert_eq!(obj.positions.len(), 5);
    assert_eq!(obj.positions[4], [0.0, 0.0, 1.0]);
    assert_eq!(obj.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 4], [0, 1, 4], [0, 1, 4], [0, 1, 4]]);
    assert_eq!(obj.triangle_polygon, vec![0, 0, 1, 2, 3, 4]);
    assert_eq!(obj.n_polygons, 5);
    assert_eq!(obj.groups, vec![String::new()]);
    assert_eq!(obj.triangle_group, vec![0; 6]);
}

#[test]
fn obj_negative_indices_polygons_groups_and_continuations() {
    let text = "o first\n\
                v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv -1 0.5 0\n\
                f -5 -4 -3 -2 -1   # a pentagon, relative indices\n\
                g second extra\n\
                v 2 0 0\n\
                f 2 6 \\\n  3\n\
                s off\nusemtl skin\n\
                g first\n\
                f 1 2 4\n";
    let obj = Obj::parse(text).unwrap();
    assert_eq!(obj.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 5, 2], [0, 1, 3]]);
    assert_eq!(obj.groups, vec!["first".to_string(), "second extra".to_string()]);
    assert_eq!(obj.triangle_group, vec![0, 0, 0, 1, 0]);
    assert_eq!(obj.group_index("extra"), Some(1));
    assert_eq!(obj.group_index("nope"), None);
    assert_eq!(obj.triangles_in_groups(&["first"]).unwrap(), vec![0, 1, 2, 4]);
    assert_eq!(obj.triangles_in_groups(&["second"]).unwrap(), vec![3]);
    assert_eq!(obj.triangles_in_groups(&["second", "first"]).unwrap(), vec![0, 1, 2, 3, 4]);
    assert!(matches!(obj.triangles_in_groups(&["nope"]), Err(Error::Parse { line: 0, .. })));
    // The continued face reports errors at its first line.
    let (line, _) = parse_err("v 0 0 0\nv 1 0 0\nf 1 2 \\\n 9\n");
    assert_eq!(line, 3);
}

#[test]
fn obj_extract_groups_is_compact() {
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 5 5 5\nv 6 5 5\nv 6 6 5\n\
                g a\nf 5 6 7\ng b\nf 1 2 3\nf 1 3 4\n";
    let mut obj = Obj::parse(text).unwrap();
    obj.scale(0.1);
    let a = obj.extract_groups(&["a"]).unwrap();
    assert_eq!(a.faces, vec![[0, 1, 2]]);
    assert_eq!(a.remap.new_to_old, vec![4, 5, 6]);
    assert_eq!(a.rest[1], [0.6, 0.5, 0.5]);
    let b = obj.extract_groups(&["b"]).unwrap();
    assert_eq!(b.rest.len(), 4);
    assert_eq!(b.faces, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(b.remap.old_to_new[4], None);
}

#[test]
fn obj_split_components_counts_pieces() {
    // Two quads sharing no vertex, plus an unused vertex, plus a quad touching the first at a
    // single vertex (same component).
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 9 9 9\nv 5 0 0\nv 6 0 0\nv 6 1 0\nv 5 1 0\n\
                v 2 1 0\nv 2 2 0\nv 1 2 0\n\
                f 6 7 8 9\nf 1 2 3 4\nf 3 10 11 12\n";
    let obj = Obj::parse(text).unwrap();
    let parts = split_components(&obj.positions, &obj.triangles).unwrap();
    assert_eq!(parts.len(), 2);
    assert_eq!(parts[0].rest.len(), 7);
    assert_eq!(parts[0].faces.len(), 4);
    assert_eq!(parts[1].remap.new_to_old, vec![5, 6, 7, 8]);
    assert!(matches!(split_components(&obj.positions[..3], &obj.triangles), Err(Error::IndexOutOfRange { .. })));
}

#[test]
fn obj_writer_round_trips() {
    let pos = vec![[0.1f32, -2.5, 3.0e-7], [1.0, 0.0, 0.0], [0.33333334, 1.0, 0.0]];
    let tris = vec![[0u32, 1, 2]];
    let normals = [[0.0, 0.0, 1.0]; 3];
    for nr in [None, Some(&normals[..])] {
        let text = to_string(&pos, &tris, nr).unwrap();
        let back = Obj::parse(&text).unwrap();
        assert_eq!(back.positions, pos);
        assert_eq!(back.triangles, tris);
        assert_eq!(text.contains("vn "), nr.is_some());
    }
    assert!(matches!(to_string(&pos, &[[0, 1, 3]], None), Err(Error::IndexOutOfRange { index: 3, .. })));
    assert!(matches!(to_string(&pos, &tris, Some(&normals[..2])), Err(Error::SizeMismatch { .. })));
    let dir = std::env::temp_dir().join(format!("hood-obj-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("tri.obj");
    write(&file, &pos, &tris, None).unwrap();
    assert_eq!(Obj::read(&file).unwrap().positions, pos);
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(matches!(Obj::read(dir.join("missing.obj")), Err(Error::Io { .. })));
}

#[test]
fn obj_errors_name_the_line() {
    let cases: &[(&str, usize, &str)] = &[
        ("v 1 2\n", 1, "needs 3"),
        ("v 1 x 2\n", 1, "bad vertex coordinate"),
        ("\nv 1 nan 2\n", 2, "non-finite"),
        ("v 0 0 0\nv 1 0 0\nf 1 2\n", 3, "at least 3"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 0\n", 4, "index 0"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 4\n", 4, "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf -4 2 3\n", 4, "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 a\n", 4, "bad vertex index"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1/1 2 3\n", 4, "texture coordinate index 1"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nf 1//2 2 3\n", 5, "normal index 2"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1/ 2 3\n", 4, "bad texture coordinate index"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1/1 2 3\n", 6, "more than"),
        // A face may not refer forward.
        ("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 1 1 0\n", 3, "out of range"),
    ];
    for (text, line, needle) in cases {
        let (l, m) = parse_err(text);
        assert_eq!(l, *line, "{text:?}: {m}");
        assert!(m.contains(needle), "{text:?}: message '{m}' lacks '{needle}'");
    }
    // Comment-only, blank and unknown lines are fine.
    let obj = Obj::parse("# c\n\n   \nmtllib x.mtl\nl 1 2\n").unwrap();
    assert!(obj.positions.is_empty() && obj.triangles.is_empty());
}

#[test]
fn obj_keeps_texture_coordinates_normals_and_corners() {
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0.25 0.5\nvt 1 0 0\nvt 0.5\nvn 0 0 2\n\
                f 1/1/1 2/2/1 3/3/1 4/1/1\nf 1 3//1 -1/-2\n";
    let obj = Obj::parse(text).unwrap();
    assert_eq!(obj.uvs, vec![[0.25, 0.5], [1.0, 0.0], [0.5, 0.0]]);
    assert_eq!(obj.normals, vec![[0.0, 0.0, 2.0]]);
    assert_eq!(obj.face_sizes, vec![4, 3]);
    let c = |v, vt, vn| Corner { v, vt, vn };
    assert_eq!(
        obj.corners[..4],
        [c(0, Some(0), Some(0)), c(1, Some(1), Some(0)), c(2, Some(2), Some(0)), c(3, Some(0), Some(0))]
    );
    assert_eq!(obj.corners[4..], [c(0, None, None), c(2, None, Some(0)), c(3, Some(1), None)]);
    assert_eq!(obj.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
    let (line, message) = parse_err("vt\n");
    assert_eq!((line, message.as_str()), (1, "texture has 0 coordinates, needs 1"));
    let (line, message) = parse_err("v 0 0 0\nvn 0 x 1\n");
    assert_eq!((line, message.as_str()), (2, "bad normal coordinate 'x'"));
}

#[test]
fn obj_beyond_the_vertex_or_triangle_bound_is_refused() {
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
    assert!(Obj::parse_within(text, 4, 2).is_ok());
    let e = Obj::parse_within(text, 3, 2).unwrap_err();
    assert_eq!(e, Error::CapacityExceeded { what: "obj vertices", capacity: 3, needed: 4 });
    // The quad's two triangles are counted before they are stored.
    let e = Obj::parse_within(text, 4, 1).unwrap_err();
    assert_eq!(e, Error::CapacityExceeded { what: "obj triangles", capacity: 1, needed: 2 });
}
