fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out_dir = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    let descriptors = out_dir.join("glissade_descriptor.bin");
    tonic_prost_build::configure()
        // ordered maps: parameter vectors and QoIs serialise and print the same way every time
        .btree_map(".")
        // the encoded descriptors, for server reflection (`grpcurl list`) and the JSON below
        .file_descriptor_set_path(&descriptors)
        .compile_protos(&["proto/glissade.proto", "proto/ranks.proto"], &["proto"])?;
    // The messages' JSON (serde, proto3's JSON mapping): what the web API serves and `--json`
    // prints. Fields by their .proto names, every field written (defaults too), enums by name,
    // 64-bit integers as strings. Rank 0's messages to its ranks are never JSON.
    pbjson_build::Builder::new()
        .register_descriptors(&std::fs::read(&descriptors)?)?
        .btree_map(["."])
        .preserve_proto_field_names()
        .emit_fields()
        .exclude([".glissade.v1.RankMessage", ".glissade.v1.RankJob", ".glissade.v1.RankScene"])
        .build(&[".glissade.v1"])?;
    Ok(())
}
