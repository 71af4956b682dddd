fn main() {
    println!("skybake {}", env!("CARGO_PKG_VERSION"));
}
