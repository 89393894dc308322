use subdiv::*;
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let s = Surface::load_obj(&path).unwrap();
    println!("{}", s.num_base_quads());
}
