//! The same data in raw, NRRD (raw and gzip), MetaImage (.mhd, .mha) and NIfTI renders the
//! same image.

mod common;

use std::io::Write;

use pofvr::frame::{render_reference, RenderJob};
use pofvr::render::{families, Camera, Image, Projection, RenderSettings};
use pofvr::volume::phantom::Phantom;
use pofvr::volume::{DataType, RawSpec, Volume, VoxelData};

fn render(vol: Volume) -> Image {
    let tf = families::for_phantom(Phantom::SheppLogan);
    let job = RenderJob::new(vol, tf, 8, RenderSettings::default()).unwrap();
    let cam = Camera::orbit(&job.volume, 25.0, 15.0, 48, 40, Projection::Orthographic);
    render_reference(&job, &cam).0
}

#[test]
fn every_format_of_the_phantom_renders_the_same_image() {
    let ph = Phantom::SheppLogan.generate(30);
    let VoxelData::U8(v) = ph.data() else {
        unreachable!()
    };
    let bytes = v.as_slice().to_vec();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("v.raw"), &bytes).unwrap();
    let nrrd_head = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 30 30 30\nspacings: 1.5 1 1\n";
    let mut f = std::fs::File::create(d.join("a.nrrd")).unwrap();
    write!(f, "{nrrd_head}encoding: raw\n\n").unwrap();
    f.write_all(&bytes).unwrap();
    let mut f = std::fs::File::create(d.join("g.nrrd")).unwrap();
    write!(f, "{nrrd_head}encoding: gzip\n\n").unwrap();
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    gz.write_all(&bytes).unwrap();
    f.write_all(&gz.finish().unwrap()).unwrap();
    std::fs::write(
        d.join("m.mhd"),
        "ObjectType = Image\nNDims = 3\nDimSize = 30 30 30\nElementSpacing = 1.5 1 1\nElementType = MET_UCHAR\nElementDataFile = v.raw\n",
    )
    .unwrap();
    let mut f = std::fs::File::create(d.join("l.mha")).unwrap();
    write!(f, "ObjectType = Image\nNDims = 3\nDimSize = 30 30 30\nElementSpacing = 1.5 1 1\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n").unwrap();
    f.write_all(&bytes).unwrap();
    drop(f);
    let mut spec = RawSpec::new([30; 3], DataType::U8);
    spec.spacing = [1.5, 1.0, 1.0];
    let reference = render(Volume::open(&d.join("v.raw"), Some(&spec)).unwrap());
    assert!(reference.mean_alpha() > 0.05);
    for name in ["a.nrrd", "g.nrrd", "m.mhd", "l.mha"] {
        let img = render(Volume::open(&d.join(name), None).unwrap());
        assert_eq!(img.max_abs_diff(&reference), Some(0.0), "{name}");
    }
}

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn real_nifti_nrrd_and_metaimage_render_the_same_image() {
    let data = common::shared_data().join("ch2better_mri");
    let a = render(Volume::open(&data.join("ch2better_mri.nhdr"), None).unwrap());
    for other in ["ch2better_mri.mhd", "source/ch2better.nii.gz"] {
        let b = render(Volume::open(&data.join(other), None).unwrap());
        assert_eq!(a.max_abs_diff(&b), Some(0.0), "{other}");
    }
}
