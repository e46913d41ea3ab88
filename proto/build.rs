fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out_dir = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    tonic_prost_build::configure()
        // ordered maps: parameter vectors and QoIs serialise and print the same way every time
        .btree_map(".")
        // the encoded descriptors, for server reflection (`grpcurl list`)
        .file_descriptor_set_path(out_dir.join("glissade_descriptor.bin"))
        .compile_protos(&["proto/glissade.proto", "proto/ranks.proto"], &["proto"])?;
    Ok(())
}
