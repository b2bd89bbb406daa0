fn main() {
    std::process::exit(raylab::main());
}
