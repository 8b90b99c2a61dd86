//! The exports of `hood::io::export` read back: an OBJ with texture coordinates written again
//! with new positions, PC2 and MDD by readers of their published layouts, the `.usda` stage by a
//! small reader (and by the USD library when `python3 -c "import pxr"` works), and `hood
//! simulate --export` writing them all.
#![cfg(feature = "tools")]

use hood::io::export::{mdd, pc2, usda, ExportMesh, ObjTemplate};
use hood::io::obj::Obj;

/// A grid of `n` x `n` vertices, `h` apart, at height `y`: quads with texture coordinates, two
/// groups (the last row of quads in `hem`), a material and per-corner normals.
fn grid_obj(n: usize, h: f32, y: f32) -> String {
    let mut s = String::from("# a test cloth\nmtllib cloth.mtl\no cloth\n");
    for i in 0..n * n {
        let (c, r) = ((i % n) as f32, (i / n) as f32);
        s += &format!("v {} {y} {}\n", c * h - 0.5 * h * (n - 1) as f32, r * h - 0.5 * h * (n - 1) as f32);
    }
    for i in 0..n * n {
        s += &format!("vt {} {}\n", (i % n) as f32 / (n - 1) as f32, (i / n) as f32 / (n - 1) as f32);
    }
    s += "vn 0 1 0\nusemtl linen\ng body\n";
    for r in 0..n - 1 {
        if r == n - 2 {
            s += "g hem\n";
        }
        for c in 0..n - 1 {
            let v = r * n + c + 1;
            let q = [v, v + n, v + n + 1, v + 1];
            s += &format!("f {}\n", q.map(|v| format!("{v}/{v}/1")).join(" "));
        }
    }
    s
}

/// A two-frame body OBJ sequence in `dir`: a tetrahedron 1 m high that drops 1 cm.
fn write_dropping_body(dir: &std::path::Path) {
    std::fs::create_dir_all(dir).unwrap();
    for (f, dy) in [0.0f32, -0.01].into_iter().enumerate() {
        let body = hood::io::obj::to_string(
            &[[-0.4, dy, -0.4], [0.4, dy, -0.4], [0.0, dy, 0.4], [0.0, 1.0 + dy, 0.0]],
            &[[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]],
            None,
        )
        .unwrap();
        std::fs::write(dir.join(format!("{f}.obj")), body).unwrap();
    }
}

fn moved(positions: &[[f32; 3]], t: f32) -> Vec<[f32; 3]> {
    positions.iter().map(|p| [p[0] + 0.1 * t, p[1] - 0.01 * t * p[0], p[2] + 0.003 * t]).collect()
}

#[test]
fn export_obj_with_uvs_round_trips_with_new_positions() {
    let text = grid_obj(4, 0.1, 1.0);
    let t = ObjTemplate::parse(&text).unwrap();
    let input = Obj::parse(&text).unwrap();
    let positions = moved(&input.positions, 2.0);
    let mut out = Vec::new();
    t.write(&mut out, &positions).unwrap();
    let written = String::from_utf8(out).unwrap();
    let back = Obj::parse(&written).unwrap();
    assert_eq!(back.positions, positions, "positions are written exactly");
    assert_eq!((&back.uvs, &back.corners, &back.face_sizes), (&input.uvs, &input.corners, &input.face_sizes));
    assert_eq!((&back.groups, &back.triangle_group), (&input.groups, &input.triangle_group));
    // Every line but the vertices and the normal is as written.
    let kept = |s: &str| s.lines().filter(|l| !l.starts_with("v ") && !l.starts_with("vn ")).collect::<String>();
    assert_eq!(kept(&written), kept(&text));
    // The normal follows the cloth: y up in the input, leaning towards +x as the cloth dips along x.
    let n = back.normals[0];
    assert!((n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 1e-5 && n[1] > 0.99 && n[0] > 0.0, "{n:?}");
}

fn frames(n_frames: usize) -> Vec<Vec<[f32; 3]>> {
    let rest = Obj::parse(&grid_obj(3, 0.2, 1.2)).unwrap().positions;
    (0..n_frames).map(|f| moved(&rest, f as f32)).collect()
}

fn i32_at(b: &[u8], at: usize, big: bool) -> i32 {
    let w = b[at..at + 4].try_into().unwrap();
    if big {
        i32::from_be_bytes(w)
    } else {
        i32::from_le_bytes(w)
    }
}

fn f32s(b: &[u8], big: bool) -> Vec<f32> {
    b.chunks_exact(4)
        .map(
            |w| if big { f32::from_be_bytes(w.try_into().unwrap()) } else { f32::from_le_bytes(w.try_into().unwrap()) },
        )
        .collect()
}

#[test]
fn export_pc2_reads_back_exactly() {
    let frames = frames(4);
    let mut b = Vec::new();
    pc2::write(&mut b, &frames).unwrap();
    let n = frames[0].len();
    assert_eq!(b.len(), 32 + 4 * 12 * n);
    assert_eq!(&b[..12], b"POINTCACHE2\0");
    assert_eq!((i32_at(&b, 12, false), i32_at(&b, 16, false)), (1, n as i32));
    assert_eq!(f32s(&b[20..28], false), [0.0, 1.0], "start frame 0, one sample per frame");
    assert_eq!(i32_at(&b, 28, false), 4);
    let points = f32s(&b[32..], false);
    assert_eq!(points, frames.iter().flatten().flatten().copied().collect::<Vec<f32>>());
}

#[test]
fn export_mdd_reads_back_exactly() {
    let frames = frames(3);
    let mut b = Vec::new();
    mdd::write(&mut b, &frames).unwrap();
    let n = frames[0].len();
    assert_eq!(b.len(), 8 + 4 * 3 + 3 * 12 * n);
    assert_eq!((i32_at(&b, 0, true), i32_at(&b, 4, true)), (3, n as i32));
    assert_eq!(f32s(&b[8..20], true), [0.0, 1.0 / 30.0, 2.0 / 30.0], "seconds at 30 Hz");
    let points = f32s(&b[20..], true);
    assert_eq!(points, frames.iter().flatten().flatten().copied().collect::<Vec<f32>>());
}

/// The numbers of the `.usda` text after `key` up to the bracket that closes its list.
fn usda_numbers(text: &str, key: &str) -> Vec<f32> {
    let at = text.find(key).unwrap_or_else(|| panic!("no {key}")) + key.len();
    let body = &text[at..];
    let end = body.find(']').unwrap();
    body[..end]
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
        .filter(|t| !t.is_empty())
        .map(|t| t.parse().unwrap())
        .collect()
}

fn stage(frames: &[Vec<[f32; 3]>]) -> (String, ExportMesh) {
    let obj = Obj::parse(&grid_obj(3, 0.2, 1.2)).unwrap();
    let mesh = ExportMesh::from_obj(&obj);
    let mut b = Vec::new();
    usda::write(&mut b, &[usda::UsdMesh { name: "garment", mesh: &mesh, frames }]).unwrap();
    (String::from_utf8(b).unwrap(), mesh)
}

#[test]
fn export_usda_reads_back() {
    let frames = frames(3);
    let (text, mesh) = stage(&frames);
    assert!(text.starts_with("#usda 1.0\n"));
    for line in
        ["metersPerUnit = 1", "upAxis = \"Y\"", "timeCodesPerSecond = 30", "startTimeCode = 0", "endTimeCode = 2"]
    {
        assert!(text.contains(line), "{line} missing");
    }
    let ints = |key| usda_numbers(&text, key).into_iter().map(|x| x as u32).collect::<Vec<_>>();
    assert_eq!(ints("faceVertexCounts = "), mesh.face_sizes);
    assert_eq!(ints("faceVertexIndices = "), mesh.corners);
    let (uvs, uv_indices) = mesh.uvs.clone().unwrap();
    assert_eq!(usda_numbers(&text, "primvars:st = "), uvs.concat());
    assert_eq!(ints("primvars:st:indices = "), uv_indices);
    assert!(text.contains("interpolation = \"faceVarying\""));
    let flat = |f: &Vec<[f32; 3]>| f.iter().flatten().copied().collect::<Vec<f32>>();
    assert_eq!(usda_numbers(&text, "point3f[] points = "), flat(&frames[0]));
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(usda_numbers(&text, &format!("        {i}: ")), flat(f), "time sample {i}");
    }
}

/// The USD library opens the stage and reads the same points at time code 2, when it is
/// installed (`pip install usd-core`); skipped with a message otherwise.
#[test]
fn export_usda_opens_in_the_usd_library() {
    let has_pxr =
        std::process::Command::new("python3").args(["-c", "import pxr"]).output().is_ok_and(|o| o.status.success());
    if !has_pxr {
        println!("skipped: python3 -c \"import pxr\" fails (pip install usd-core to run this test)");
        return;
    }
    let frames = frames(3);
    let (text, mesh) = stage(&frames);
    let path = std::env::temp_dir().join(format!("hood-export-test-{}.usda", std::process::id()));
    std::fs::write(&path, text).unwrap();
    let script = "import sys\nfrom pxr import Usd, UsdGeom\n\
                  s = Usd.Stage.Open(sys.argv[1])\n\
                  m = UsdGeom.Mesh(s.GetDefaultPrim())\n\
                  print(s.GetStartTimeCode(), s.GetEndTimeCode(), s.GetTimeCodesPerSecond(), \
                  UsdGeom.GetStageMetersPerUnit(s), UsdGeom.GetStageUpAxis(s))\n\
                  print(len(m.GetFaceVertexCountsAttr().Get()), len(UsdGeom.PrimvarsAPI(m).GetPrimvar('st').Get()))\n\
                  print(' '.join(repr(c) for p in m.GetPointsAttr().Get(2) for c in p))\n";
    let o = std::process::Command::new("python3").args(["-c", script]).arg(&path).output().unwrap();
    let _ = std::fs::remove_file(&path);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8(o.stdout).unwrap();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines[0], "0.0 2.0 30.0 1.0 Y");
    let uvs = mesh.uvs.as_ref().unwrap().0.len();
    assert_eq!(lines[1], format!("{} {uvs}", mesh.face_sizes.len()));
    let points: Vec<f32> = lines[2].split(' ').map(|t| t.parse().unwrap()).collect();
    assert_eq!(points, frames[2].iter().flatten().copied().collect::<Vec<f32>>());
}

/// `hood simulate --export` writes every format: on a procedural skirt, and on a garment OBJ with
/// texture coordinates over a body OBJ sequence, whose OBJ sequence keeps the texture
/// coordinates and groups; `--no-body` writes no body file.
#[cfg(feature = "cli")]
#[test]
fn export_cli_simulate_writes_every_format() {
    let out = std::env::temp_dir().join(format!("hood-export-cli-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let hood = |args: &[&str], dir: &std::path::Path| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
            .args(["simulate", "--random-model", "16", "--frames", "3", "--strip", "2"])
            .args(args)
            .arg("--out")
            .arg(dir)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let skirt = out.join("skirt");
    hood(&["--garment", "skirt", "--vertices", "300", "--export", "obj,pc2", "--export", "mdd,usda"], &skirt);
    for f in ["garment_0003.obj", "body_0003.obj", "garment.obj", "body.obj", "garment.pc2", "body.mdd", "scene.usda"] {
        assert!(skirt.join(f).exists(), "{f} missing");
    }
    let n = Obj::read(skirt.join("garment.obj")).unwrap().positions.len();
    let pc2 = std::fs::read(skirt.join("garment.pc2")).unwrap();
    assert_eq!((i32_at(&pc2, 16, false), i32_at(&pc2, 28, false)), (n as i32, 4));
    let usda = std::fs::read_to_string(skirt.join("scene.usda")).unwrap();
    assert!(
        usda.contains("def Mesh \"garment\"") && usda.contains("def Mesh \"body\"") && usda.contains("endTimeCode = 3")
    );

    // A 6 x 6 grid with texture coordinates over a two-frame body (a tetrahedron moving down).
    let files = out.join("files");
    write_dropping_body(&files.join("body"));
    let garment = files.join("cloth.obj");
    std::fs::write(&garment, grid_obj(6, 0.06, 1.1)).unwrap();
    let sim = files.join("out");
    let (g, b) = (garment.to_str().unwrap(), files.join("body"));
    hood(&["--garment-obj", g, "--body-obj", b.to_str().unwrap(), "--export", "obj,usda,pc2", "--no-body"], &sim);
    let input = Obj::read(&garment).unwrap();
    let last = Obj::read(sim.join("garment_0001.obj")).unwrap();
    assert_eq!((&last.uvs, &last.corners, &last.groups), (&input.uvs, &input.corners, &input.groups));
    assert_ne!(last.positions, input.positions, "the positions are the simulated ones");
    assert!(std::fs::read_dir(&sim).unwrap().all(|e| !e.unwrap().file_name().to_string_lossy().starts_with("body")));
    let usda = std::fs::read_to_string(sim.join("scene.usda")).unwrap();
    assert!(usda.contains("primvars:st") && !usda.contains("def Mesh \"body\""));
    let _ = std::fs::remove_dir_all(&out);
}

/// `hood simulate --garment-obj` options: pins by OBJ group and by a vertex list ride on a body
/// OBJ sequence (a rigid drop of 1 cm moves them by exactly that); a file in centimetres, z up,
/// with `--scale 0.01 --up z` starts where the metre, y-up file does; a bad `--pins` or
/// `--material` is refused.
#[test]
fn export_cli_own_garment_pins_scale_and_axes() {
    let out = std::env::temp_dir().join(format!("hood-own-garment-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let run = |args: &[&str], dir: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
            .args(["simulate", "--random-model", "16", "--frames", "1", "--strip", "1", "--body-obj"])
            .arg(out.join("body"))
            .args(args)
            .arg("--out")
            .arg(dir)
            .output()
            .unwrap()
    };
    let ok = |args: &[&str], dir: &std::path::Path| {
        let o = run(args, dir);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    write_dropping_body(&out.join("body"));
    let (n, h, y) = (6, 0.06, 1.1);
    let text = grid_obj(n, h, y);
    let metres = out.join("cloth.obj");
    std::fs::write(&metres, &text).unwrap();
    let input = Obj::read(&metres).unwrap();
    // The hem group: the vertices of the last row of quads.
    let hem: Vec<usize> = ((n - 2) * n..n * n).collect();
    let list = out.join("pins.txt");
    std::fs::write(&list, "# two corners\n0, 5\n").unwrap();
    for (pins, pinned) in [("group:hem", hem), (list.to_str().unwrap(), vec![0, 5])] {
        let dir = out.join(pins.replace(['/', ':'], "_"));
        ok(&["--garment-obj", metres.to_str().unwrap(), "--pins", pins], &dir);
        let last = Obj::read(dir.join("garment_0001.obj")).unwrap();
        for &v in &pinned {
            let (p, q) = (last.positions[v], input.positions[v]);
            let want = [q[0], q[1] - 0.01, q[2]];
            assert!((0..3).all(|k| (p[k] - want[k]).abs() < 1e-5), "{pins}: vertex {v} at {p:?}, want {want:?}");
        }
    }
    // The same cloth in centimetres, z up.
    let cm: String = text
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(rest) => {
                let c: Vec<f32> = rest.split_whitespace().map(|t| t.parse().unwrap()).collect();
                format!("v {} {} {}\n", c[0] * 100.0, -c[2] * 100.0, c[1] * 100.0)
            }
            None => format!("{l}\n"),
        })
        .collect();
    let centimetres = out.join("cloth-cm-z-up.obj");
    std::fs::write(&centimetres, cm).unwrap();
    let dir = out.join("cm");
    ok(&["--garment-obj", centimetres.to_str().unwrap(), "--scale", "0.01", "--up", "z", "--pins", "none"], &dir);
    let first = Obj::read(dir.join("garment_0000.obj")).unwrap();
    for (p, q) in first.positions.iter().zip(&input.positions) {
        assert!((0..3).all(|k| (p[k] - q[k]).abs() < 1e-5), "{p:?} vs {q:?}");
    }
    for (flag, value) in [("--pins", "group:nowhere"), ("--material", "silk"), ("--up", "x")] {
        let o = run(&["--garment-obj", metres.to_str().unwrap(), flag, value], &out.join("refused"));
        assert!(!o.status.success(), "{flag} {value} accepted");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(stderr.contains("hood:"), "{flag} {value}: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&out);
}
