use super::*;
use std::string::String;
use std::vec;

const QUAD: &str = "# a quad\nmtllib cloth.mtl\no cloth\nv 0 0 0\nv 1 0 0 1.0\nv 1 \\\n 1 0\nv 0 1 0\n\
                    vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 -1\nusemtl linen\ns 1\nf 1/1/1 2/2/1 3/3/1 4/4/1\n";

#[test]
fn obj_template_replaces_only_vertices_and_normals() {
    let t = ObjTemplate::parse(QUAD).unwrap();
    let moved = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.5, 0.0], [0.0, 0.5, 0.0]];
    let mut out = Vec::new();
    t.write(&mut out, &moved).unwrap();
    let text = String::from_utf8(out).unwrap();
    // The continued vertex is one line now; the normal follows the (counter-clockwise) quad.
    let expected = "# a quad\nmtllib cloth.mtl\no cloth\nv 0 0 0\nv 2 0 0\nv 2 0.5 0\nv 0 0.5 0\n\
                    vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nusemtl linen\ns 1\nf 1/1/1 2/2/1 3/3/1 4/4/1\n";
    assert_eq!(text, expected);
    // Unchanged positions and no normals give the file back, byte for byte.
    let plain = "v 0 0 0 # origin\r\nv 1 0 0\r\nv 0 1 0\r\ng a\r\nf 1 2 3";
    let t = ObjTemplate::parse(plain).unwrap();
    let mut out = Vec::new();
    t.write(&mut out, &t.obj().positions).unwrap();
    assert_eq!(String::from_utf8(out).unwrap(), "v 0 0 0\nv 1 0 0\nv 0 1 0\ng a\r\nf 1 2 3");
}

#[test]
fn obj_template_refuses_wrong_positions() {
    let t = ObjTemplate::parse(QUAD).unwrap();
    let e = t.write(Vec::new(), &[[0.0; 3]; 3]).unwrap_err();
    assert!(matches!(e, Error::SizeMismatch { expected: 4, got: 3, .. }), "{e}");
    let e = t.write(Vec::new(), &[[0.0, f32::NAN, 0.0]; 4]).unwrap_err();
    assert!(matches!(e, Error::NonFinite { index: 0, .. }), "{e}");
}

#[test]
fn export_mesh_keeps_polygons_and_uvs_only_when_every_corner_has_one() {
    let obj = Obj::parse(QUAD).unwrap();
    let m = ExportMesh::from_obj(&obj);
    assert_eq!(m.face_sizes, vec![4]);
    assert_eq!(m.corners, vec![0, 1, 2, 3]);
    assert_eq!(m.uvs, Some((vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], vec![0, 1, 2, 3])));
    let mixed = Obj::parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2 3\n").unwrap();
    assert_eq!(ExportMesh::from_obj(&mixed).uvs, None);
    let t = ExportMesh::from_triangles(&[[0, 1, 2], [2, 1, 3]]);
    assert_eq!((t.face_sizes, t.corners), (vec![3, 3], vec![0, 1, 2, 2, 1, 3]));
}

#[test]
fn writers_refuse_bad_frames_and_meshes() {
    let none: &[Vec<[f32; 3]>] = &[];
    assert!(matches!(pc2::write(Vec::new(), none), Err(Error::Empty { .. })));
    let ragged = [vec![[0.0; 3]; 3], vec![[0.0; 3]; 2]];
    assert!(matches!(mdd::write(Vec::new(), &ragged), Err(Error::SizeMismatch { expected: 3, got: 2, .. })));
    let frames = [vec![[0.0; 3]; 3]];
    let tri = ExportMesh::from_triangles(&[[0, 1, 3]]);
    let m = |name, mesh| usda::UsdMesh { name, mesh, frames: &frames };
    let e = usda::write(Vec::new(), &[m("garment", &tri)]).unwrap_err();
    assert!(matches!(e, Error::IndexOutOfRange { at: 2, index: 3, len: 3, .. }), "{e}");
    let tri = ExportMesh::from_triangles(&[[0, 1, 2]]);
    let e = usda::write(Vec::new(), &[m("2garment", &tri)]).unwrap_err();
    assert!(e.to_string().contains("not an identifier"), "{e}");
}
