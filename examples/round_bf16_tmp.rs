use hood::model::{write_model, ModelBytes};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mb = ModelBytes::read(&a[1]).unwrap();
    let m = mb.model().unwrap();
    let mut p = m.to_params();
    let n_enc = p.mlps.encoders().count();
    for (i, mlp) in p.mlps.iter_mut().enumerate() {
        if i < n_enc {
            continue;
        }
        for l in &mut mlp.layers {
            for w in &mut l.weight {
                *w = half::bf16::from_f32(*w).to_f32();
            }
        }
    }
    let prov: Vec<(String, String)> = m.provenance().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    let prov: Vec<(&str, &str)> = prov.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    std::fs::write(&a[2], write_model(&p, true, &prov).unwrap()).unwrap();
}
