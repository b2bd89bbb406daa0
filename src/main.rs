fn main() {
    std::process::exit(raylab::cli::main());
}
