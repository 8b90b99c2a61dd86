use super::*;
use crate::model::spec::ModelSpec;

fn small() -> Params {
    let spec = ModelSpec::with_schedule(16, 2, 2, "f,c0 | d:c0,c1 | u:f,c0").unwrap();
    let mut p = Params::init(&spec, 11).unwrap();
    p.normalisers.node.accumulate(&[0.5; 42], 21);
    p.normalisers.node.accumulate(&[1.5; 21], 21);
    p
}

#[test]
fn model_file_round_trip_reads_weights_in_place() {
    let p = small();
    let bytes = ModelBytes::new(&write_model(&p, true, &[("note", "test")]).unwrap());
    let m = bytes.model().unwrap();
    assert_eq!(m.spec(), &p.spec);
    assert!(m.has_bf16());
    assert_eq!(m.provenance().collect::<Vec<_>>(), vec![("note", "test")]);
    // Zero copy: every weight slice points into the caller's buffer.
    let range = bytes.as_bytes().as_ptr_range();
    let inside =
        |s: &[f32]| range.contains(&(s.as_ptr() as *const u8)) && s.as_ptr_range().end as *const u8 <= range.end;
    for v in m.mlps.iter() {
        for l in &v.layers {
            assert!(inside(l.bias));
            for w in &l.f32 {
                let Weights::F32(w) = w else { panic!("f32 part expected") };
                assert!(inside(w.data()));
            }
            assert_eq!(l.bf16.len(), l.f32.len());
        }
    }
    assert!(inside(m.node_type_embedding));
    // The master parameters come back exactly.
    assert_eq!(m.to_params(), p);
    let (mean, _) = m.node_stats();
    assert!((mean[0] - 2.5 / 3.0).abs() < 1e-6);
}

#[test]
fn model_file_weights_start_on_cache_lines_and_load_from_any_aligned_buffer() {
    let p = small();
    let file = write_model(&p, true, &[("note", "an entry long enough to shift what follows")]).unwrap();
    let bytes = ModelBytes::new(&file);
    assert!((bytes.as_bytes().as_ptr() as usize).is_multiple_of(WEIGHT_ALIGN));
    let m = bytes.model().unwrap();
    let mut arrays = 0;
    for v in m.mlps.iter() {
        for l in &v.layers {
            for w in l.f32.iter().chain(&l.bf16) {
                let start = match w {
                    Weights::F32(w) => w.data().as_ptr() as usize,
                    Weights::Bf16(w) => w.data().as_ptr() as usize,
                };
                assert!(start.is_multiple_of(WEIGHT_ALIGN), "a weight array at offset {}", start % WEIGHT_ALIGN);
                arrays += 1;
            }
        }
    }
    assert!(arrays > 20, "{arrays}");
    // The padding is the writer's only: a buffer aligned to 16 bytes but not to 64 reads the
    // same model.
    let mut shifted = rkyv::util::AlignedVec::<WEIGHT_ALIGN>::new();
    shifted.extend_from_slice(&[0; ALIGN]);
    shifted.extend_from_slice(&file);
    let m16 = Model::from_bytes(&shifted[ALIGN..]).unwrap();
    assert_eq!(m16.to_params(), p);
}

#[test]
fn model_file_refuses_truncation_at_every_length() {
    let bytes = write_model(&small(), false, &[]).unwrap();
    for cut in 0..bytes.len() {
        let b = ModelBytes::new(&bytes[..cut]);
        assert!(b.model().is_err(), "truncated at {cut} of {} accepted", bytes.len());
    }
}

/// The same archive under a version-1 header (no checksum), as files written before it were.
fn as_version_1(bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[8..12].copy_from_slice(&1u32.to_le_bytes());
    b[12..16].copy_from_slice(&0u32.to_le_bytes());
    b
}

#[test]
fn model_file_refuses_every_damaged_byte_and_bit() {
    // Every byte of a tiny model changed: all refused by the checksum.
    let spec = ModelSpec::with_schedule(4, 2, 2, "f,c0").unwrap();
    let tiny = write_model(&Params::init(&spec, 3).unwrap(), true, &[]).unwrap();
    for i in 0..tiny.len() {
        let mut b = tiny.clone();
        b[i] ^= 0x5A;
        assert!(ModelBytes::new(&b).model().is_err(), "byte {i} of {} changed and the file loaded", tiny.len());
    }
    // Single bits at many positions of a larger one.
    let bytes = write_model(&small(), true, &[]).unwrap();
    for i in (0..bytes.len()).step_by(997) {
        let mut b = bytes.clone();
        b[i] ^= 0x5A;
        assert!(ModelBytes::new(&b).model().is_err(), "byte {i} changed and the file loaded");
    }
    let mut rng = crate::rng::Rng::new(5);
    for _ in 0..3000 {
        let mut b = bytes.clone();
        let bit = rng.below(b.len() * 8);
        b[bit / 8] ^= 1 << (bit % 8);
        let e = ModelBytes::new(&b).model().unwrap_err();
        assert!(matches!(e, Error::CorruptData { .. }), "bit {bit}: {e:?}");
    }
}

#[test]
fn model_file_bit_flips_without_a_checksum_are_errors_not_panics() {
    let bytes = as_version_1(&write_model(&small(), true, &[]).unwrap());
    assert!(ModelBytes::new(&bytes).model().is_ok(), "a version-1 file loads");
    let mut rng = crate::rng::Rng::new(5);
    let (mut refused, mut accepted) = (0, 0);
    for _ in 0..3000 {
        let mut b = bytes.clone();
        let bit = rng.below(b.len() * 8);
        b[bit / 8] ^= 1 << (bit % 8);
        // A flip inside a weight is still a valid file (a different model); a flip in the
        // structure must be refused. Either way: no panic, and what loads is self-consistent.
        match ModelBytes::new(&b).model() {
            Ok(m) => {
                accepted += 1;
                let _ = m.to_params();
            }
            Err(e) => {
                refused += 1;
                assert!(
                    matches!(e, Error::CorruptData { .. } | Error::IncompatibleModel { .. } | Error::Parse { .. }),
                    "{e:?}"
                );
            }
        }
    }
    assert!(refused > 0 && accepted > 0, "refused {refused}, accepted {accepted}");
}

#[test]
fn model_file_refuses_other_versions_and_misalignment() {
    let mut bytes = write_model(&small(), false, &[]).unwrap();
    let aligned = ModelBytes::new(&bytes);
    assert!(aligned.model().is_ok());
    let mut shifted = rkyv::util::AlignedVec::<16>::new();
    shifted.push(0);
    shifted.extend_from_slice(&bytes);
    assert_eq!(
        Model::from_bytes(&shifted[1..]).unwrap_err(),
        Error::CorruptData { reason: "model buffer is not 16-byte aligned" }
    );
    bytes[8] = 3;
    assert_eq!(
        ModelBytes::new(&bytes).model().unwrap_err(),
        Error::CorruptData { reason: "unsupported .hood format version" }
    );
    bytes[8] = 2;
    bytes[0] = b'X';
    assert!(ModelBytes::new(&bytes).model().is_err());
}

#[test]
fn model_file_whose_spec_exceeds_the_memory_budget_is_refused_before_its_layers() {
    let bytes = ModelBytes::new(&write_model(&small(), false, &[]).unwrap());
    let mut rec = rkyv::from_bytes::<ModelRec, rkyv::rancor::Error>(&bytes.as_bytes()[HEADER_LEN..]).unwrap();
    // The widest latent the spec allows: about 7 GB of weights for this schedule.
    rec.latent = 4096;
    let archive = rkyv::to_bytes::<rkyv::rancor::Error>(&rec).unwrap();
    let file = ModelBytes::new(&with_header(&archive));
    match Model::from_bytes(file.as_bytes()) {
        Err(Error::CapacityExceeded { what, capacity, needed }) => {
            assert_eq!((what, capacity), ("model weights (bytes, f32 and bf16)", crate::limits::MAX_MODEL_BYTES));
            assert!(needed > 6 << 30, "{needed}");
        }
        other => panic!("expected CapacityExceeded, got {other:?}"),
    }
}
