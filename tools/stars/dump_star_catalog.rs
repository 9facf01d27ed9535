// One-off, in a scratch crate with `star-catalog = { version = "0.2.0", features = ["hipp_bright"] }`:
// `cargo run --release > /tmp/hipp_bright.csv`; then tools/stars/join_hip2.py.
//! Dumps star-catalog 0.2.0's bundled Hipparcos stars (feature hipp_bright,
//! V <= 8.0) as CSV: hip, ra_rad, dec_rad, v_mag, b_v.
fn main() {
    let cat = star_catalog::Catalog::load_catalog("hipp_bright", 8.0).expect("hipp_bright");
    println!("hip,ra_rad,dec_rad,v_mag,b_v");
    for s in cat.iter_stars() {
        println!("{},{:.10},{:.10},{},{}", s.id(), s.ra(), s.de(), s.magnitude(), s.bv());
    }
}
