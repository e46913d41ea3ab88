//! The system pieces the project stands on: MPI ranks, HDF5, sled.

use crate::common::*;

#[test]
fn mpiexec_runs_two_ranks_and_all_reduces() {
    let bin = env!("CARGO_BIN_EXE_mpi-allreduce");
    let out = run_with_timeout(Command::new("mpiexec.mpich").args(["-n", "2", bin]), LIMIT);
    assert!(out.status.success(), "mpiexec failed ({}):\n{}", out.status, text(&out.stderr));
    assert_eq!(text(&out.stdout).trim(), "size=2 sum=3");
}

#[test]
fn hdf5_round_trip_of_a_2d_dataset_and_attribute() -> anyhow::Result<()> {
    let _locks_files = no_children();
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("fields.h5");
    // Thirds are not exactly representable in decimal, so a lossy path (text, f32) would show.
    let (rows, cols) = (3, 4);
    let data: Vec<f64> = (0..rows * cols).map(|i| f64::from(i as u32) / 3.0).collect();
    let time = 0.1_f64 + 0.2;
    {
        let file = hdf5::File::create(&path)?;
        let ds = file.new_dataset::<f64>().shape((rows, cols)).create("displacement")?;
        ds.write_raw(&data[..])?;
        ds.new_attr::<f64>().create("time")?.write_scalar(&time)?;
    }
    let file = hdf5::File::open(&path)?;
    let ds = file.dataset("displacement")?;
    assert_eq!(ds.shape(), vec![rows, cols]);
    let back: Vec<f64> = ds.read_raw()?;
    assert_eq!(
        back.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        data.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    assert_eq!(ds.attr("time")?.read_scalar::<f64>()?.to_bits(), time.to_bits());
    Ok(())
}

#[test]
fn sled_survives_flush_drop_and_reopen() -> anyhow::Result<()> {
    let _locks_files = no_children();
    let dir = tempfile::tempdir()?;
    {
        let db = sled::open(dir.path())?;
        for i in 0_u32..100 {
            db.insert(i.to_be_bytes(), format!("value {i}").as_bytes())?;
        }
        db.flush()?;
    }
    let db = sled::open(dir.path())?;
    assert_eq!(db.len(), 100);
    for i in 0_u32..100 {
        let v = db.get(i.to_be_bytes())?.expect("key written before reopen");
        assert_eq!(&*v, format!("value {i}").as_bytes());
    }
    Ok(())
}
