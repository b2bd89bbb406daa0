/// One line and exit status 1 when memory runs out, not an abort.
#[global_allocator]
static ALLOCATOR: raylab::os::OutOfMemoryIsAnError = raylab::os::OutOfMemoryIsAnError;

fn main() {
    std::process::exit(raylab::cli::main());
}
