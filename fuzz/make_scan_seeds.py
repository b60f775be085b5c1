#!/usr/bin/python3
"""Seeds for fuzz_nifti, fuzz_tiff and fuzz_dicom (docs/hardening.md), written by other
libraries than the readers': nibabel (NIfTI-1/2, gzip, big-endian, sform/qform, scaling),
tifffile (multi-page strips and tiles, deflate, LZMA, a predictor, ImageJ, a folder of slices) and pydicom
(small series of every pixel type, and python3-pydicom's real test slices: big-endian, implicit
VR, RLE, JPEG, JPEG 2000, JPEG-LS, deflate). Files of a folder are joined with the separator
of fuzz/FuzzCommon.h. A library that is missing only skips its target's seeds.

    make_scan_seeds.py OUTDIR     writes OUTDIR/fuzz_nifti/*, OUTDIR/fuzz_tiff/*, OUTDIR/fuzz_dicom/*
"""
import gzip
import io
import os
import sys
from pathlib import Path

import numpy as np

NEXT = b"ISOUQ-NEXT-FILE"  # kNextFile in fuzz/FuzzCommon.h


def volume(dtype, shape=(5, 4, 3)):
    """A small ball-like volume, z, y, x."""
    z, y, x = np.indices(shape[::-1]).astype(float)
    r = np.sqrt((x - 2) ** 2 + (y - 1.5) ** 2 + (z - 1) ** 2)
    v = 40 - 10 * r
    return v.astype(dtype)


def nifti(out):
    import nibabel as nib
    out.mkdir(parents=True, exist_ok=True)
    affine = np.array([[0.9, 0.1, 0, -3], [0, 1.1, 0, 2], [0, 0, 2.5, 1], [0, 0, 0, 1]])
    cases = [("u8", nib.Nifti1Image, np.uint8, "<", True, True), ("i16_be", nib.Nifti1Image, np.int16, ">", True, False),
             ("f32_qform", nib.Nifti1Image, np.float32, "<", False, True), ("f64_n2", nib.Nifti2Image, np.float64, "<", True, True),
             ("u16_n2_be", nib.Nifti2Image, np.uint16, ">", False, False)]
    for name, cls, dtype, order, sform, qform in cases:
        data = volume(np.dtype(dtype).newbyteorder(order)).transpose(2, 1, 0)  # x, y, z
        image = cls(data, affine)
        image.header.set_data_dtype(np.dtype(dtype).newbyteorder(order))
        image.set_sform(affine if sform else None, code=1 if sform else 0)
        image.set_qform(affine if qform else None, code=1 if qform else 0)
        if name == "i16_be":
            image.header.set_slope_inter(0.5, -3.0)
        raw = image.to_bytes()
        (out / f"{name}.nii").write_bytes(raw)
        if name in ("u8", "f64_n2"):
            (out / f"{name}.nii.gz").write_bytes(gzip.compress(raw, mtime=0))


def tiff(out):
    import tifffile
    out.mkdir(parents=True, exist_ok=True)
    stack = volume(np.uint8)  # pages z of y rows, x columns
    for name, dtype, options in [("u8", np.uint8, {}), ("i16_tiles", np.int16, {"tile": (16, 16)}),
                                 ("f32_deflate", np.float32, {"compression": "zlib"}),
                                 ("u16_lzma", np.uint16, {"compression": "lzma"}),
                                 ("i16_predictor", np.int16, {"compression": "zlib", "predictor": True}), ("f64", np.float64, {}),
                                 ("u32", np.uint32, {})]:
        buffer = io.BytesIO()
        tifffile.imwrite(buffer, stack.astype(dtype), photometric="minisblack", **options)
        (out / f"{name}.tif").write_bytes(buffer.getvalue())
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, stack.astype(np.uint16), imagej=True, resolution=(2.0, 4.0 / 3.0),
                     metadata={"spacing": 2.5, "unit": "um"})
    (out / "imagej.tif").write_bytes(buffer.getvalue())
    pages = []
    for page in stack:
        buffer = io.BytesIO()
        tifffile.imwrite(buffer, page, photometric="minisblack")
        pages.append(buffer.getvalue())
    (out / "folder").write_bytes(NEXT.join(pages))


def dicom_slice(dtype, k, values, series, little=True, implicit=False):
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, ExplicitVRBigEndian, ImplicitVRLittleEndian
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = CTImageStorage
    meta.MediaStorageSOPInstanceUID = f"1.2.3.4.5.{k}"
    meta.TransferSyntaxUID = ImplicitVRLittleEndian if implicit else ExplicitVRLittleEndian if little else ExplicitVRBigEndian
    ds = FileDataset("slice", {}, file_meta=meta, preamble=b"\0" * 128)
    ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
    ds.StudyInstanceUID, ds.SeriesInstanceUID = "1.2.3.4", series
    ds.Modality, ds.InstanceNumber = "CT", k + 1
    ds.Rows, ds.Columns = values.shape
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    bits = np.dtype(dtype).itemsize * 8
    ds.BitsAllocated, ds.BitsStored, ds.HighBit = bits, bits, bits - 1
    ds.PixelRepresentation = 1 if np.dtype(dtype).kind == "i" else 0
    ds.ImagePositionPatient = [-3.0, 2.0, 1.0 + 2.5 * k]
    ds.ImageOrientationPatient = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    ds.PixelSpacing = [1.1, 0.9]
    ds.RescaleSlope, ds.RescaleIntercept = 0.5, -10.0
    ds.PixelData = values.astype(np.dtype(dtype).newbyteorder("<" if little else ">")).tobytes()
    ds.is_little_endian, ds.is_implicit_VR = little, implicit
    buffer = io.BytesIO()
    ds.save_as(buffer, write_like_original=False)
    return buffer.getvalue()


def dicom(out):
    import pydicom
    out.mkdir(parents=True, exist_ok=True)
    stack = volume(np.float64)
    for name, dtype, little, implicit in [("i16", np.int16, True, False), ("u16_be", np.uint16, False, False),
                                          ("u8_implicit", np.uint8, True, True), ("i32", np.int32, True, False)]:
        files = [dicom_slice(dtype, k, np.round(stack[k]), "1.2.3.4.9", little, implicit) for k in range(len(stack))]
        (out / name).write_bytes(NEXT.join(files))
    # Real slices (python3-pydicom's test data), two positions along the normal: GDCM's decoders.
    data = Path(pydicom.__file__).parent / "data" / "test_files"
    for name in ["MR_small_bigendian.dcm", "MR_small_implicit.dcm", "MR_small_RLE.dcm", "JPEG2000.dcm",
                 "JPEG-lossy.dcm", "MR_small_jpeg_ls_lossless.dcm", "MR_small_jp2klossless.dcm", "image_dfl.dcm"]:
        if not (data / name).exists():
            continue
        files = []
        for k in range(2):
            ds = pydicom.dcmread(data / name)
            position = [float(v) for v in getattr(ds, "ImagePositionPatient", [0, 0, 0])]
            if "ImageOrientationPatient" not in ds:
                ds.ImageOrientationPatient = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
            normal = np.cross(np.array(ds.ImageOrientationPatient[:3], float), np.array(ds.ImageOrientationPatient[3:], float))
            ds.ImagePositionPatient = [float(v) for v in np.array(position) + 2.0 * k * normal]
            ds.SeriesInstanceUID = "1.2.3.4.8"
            buffer = io.BytesIO()
            ds.save_as(buffer)
            files.append(buffer.getvalue())
        (out / Path(name).stem).write_bytes(NEXT.join(files))


def main():
    out = Path(sys.argv[1])
    for target, write in [("fuzz_nifti", nifti), ("fuzz_tiff", tiff), ("fuzz_dicom", dicom)]:
        try:
            write(out / target)
        except ImportError as e:
            print(f"make_scan_seeds: no seeds for {target}: {e}", file=sys.stderr)


if __name__ == "__main__":
    main()
