// scan_dicom on tiny DICOM files built byte by byte (dicom_bytes.hpp): the three uncompressed
// encodings, sequences, compressed fragments; every truncation of a valid file; malformed
// elements; pixel formats the loader refuses. Each problem names its byte, tag and expected vs
// found.

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "dicom_bytes.hpp"
#include "volume/dicom_scan.hpp"

namespace lancet::volume {
namespace {

using test::DicomDataSet;
using test::ct_slice;
using test::dicom_file;

constexpr const char* kImplicitLE = "1.2.840.10008.1.2";
constexpr const char* kExplicitLE = "1.2.840.10008.1.2.1";
constexpr const char* kExplicitBE = "1.2.840.10008.1.2.2";
constexpr const char* kRle = "1.2.840.10008.1.2.5";

DicomScan scan(const std::string& bytes) {
  return scan_dicom(std::span(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size()));
}

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(DicomScan, ThreeEncodingsGiveTheSameImageFields) {
  for (const auto& [ts, explicit_vr, big] : {std::tuple{kExplicitLE, true, false}, std::tuple{kImplicitLE, false, false},
                                             std::tuple{kExplicitBE, true, true}}) {
    const DicomScan s = scan(dicom_file(ts, ct_slice(explicit_vr, big, 5.0, "1.2.3")));
    ASSERT_EQ(s.status, DicomScanStatus::kImage) << ts << ": " << s.problem;
    EXPECT_EQ(s.transfer_syntax, ts);
    EXPECT_EQ(s.explicit_vr, explicit_vr);
    EXPECT_EQ(s.big_endian, big);
    EXPECT_EQ(s.modality, "CT");
    EXPECT_EQ(s.series_uid, "1.2.3") << "the NUL padding is not part of the UID";
    EXPECT_EQ(s.rows, 3);
    EXPECT_EQ(s.columns, 4);
    EXPECT_EQ(s.bits_allocated, 16);
    EXPECT_EQ(s.pixel_representation, 1);
    EXPECT_EQ(s.pixel_length, 24u);
    EXPECT_EQ(s.frame_bytes(), 24u);
  }
}

TEST(DicomScan, NestedSequencesAreWalked) {
  DicomDataSet inner;
  inner.text(0x0008, 0x1150, "UI", "1.2");
  DicomDataSet item;
  item.sequence(0x0008, 0x1140, {inner, inner});
  DicomDataSet d;
  d.sequence(0x0008, 0x1115, {item});
  d.raw(ct_slice(true, false, 0, "9").bytes());
  const DicomScan s = scan(dicom_file(kExplicitLE, d));
  EXPECT_EQ(s.status, DicomScanStatus::kImage) << s.problem;

  // An item that claims more bytes than its sequence holds.
  DicomDataSet bad;
  bad.element(0x0008, 0x1115, "SQ", std::string("\xFE\xFF\x00\xE0\x40\x00\x00\x00", 8) + "abcd");
  bad.raw(ct_slice(true, false, 0, "9").bytes());
  const DicomScan b = scan(dicom_file(kExplicitLE, bad));
  EXPECT_EQ(b.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(b.problem, "sequence (0008,1115)")) << b.problem;
  EXPECT_TRUE(has(b.problem, "an item of 64 bytes, found 4")) << b.problem;
}

TEST(DicomScan, DeepNestingIsRefusedBeforeTheStackIs) {
  DicomDataSet d;
  d.text(0x0008, 0x0060, "CS", "CT");
  for (int i = 0; i < kMaxDicomDepth + 2; ++i) {
    DicomDataSet outer;
    outer.sequence(0x0008, 0x1115, {d});
    d = outer;
  }
  const DicomScan s = scan(dicom_file(kExplicitLE, d));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "nested deeper than 16")) << s.problem;
}

// Every prefix of a valid file: never kImage, never a crash; cut before the marker it is not
// DICOM, after it broken (or, cut exactly between two elements before Rows, not an image).
TEST(DicomScan, EveryTruncationIsRefused) {
  for (const auto& [ts, explicit_vr, big] : {std::tuple{kExplicitLE, true, false}, std::tuple{kImplicitLE, false, false},
                                             std::tuple{kExplicitBE, true, true}}) {
    const std::string full = dicom_file(ts, ct_slice(explicit_vr, big, 5.0, "1.2.3"));
    for (std::size_t n = 0; n < full.size(); ++n) {
      const DicomScan s = scan(full.substr(0, n));
      if (n < 132) {
        EXPECT_EQ(s.status, DicomScanStatus::kNotDicom) << n;
      } else if (s.status == DicomScanStatus::kNotImage) {
        // Cut exactly between two elements before the image fields: a valid, if useless, file.
        EXPECT_EQ(s.rows, 0) << n;
      } else {
        EXPECT_EQ(s.status, DicomScanStatus::kBroken) << ts << " cut to " << n << " bytes: " << s.problem;
        EXPECT_FALSE(s.problem.empty());
      }
    }
  }
}

TEST(DicomScan, PixelDataShorterThanTheImageIsBroken) {
  const DicomScan s = scan(dicom_file(kExplicitLE, ct_slice(true, false, 0, "1", 3, 4, "CT", 10)));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "PixelData (7FE0,0010): expected 24 bytes (Rows 3 x Columns 4 x 2 bytes), found 10")) << s.problem;
  // Cut inside the pixel data: the element claims 24 bytes, the file holds fewer.
  const std::string full = dicom_file(kExplicitLE, ct_slice(true, false, 0, "1"));
  const DicomScan cut = scan(full.substr(0, full.size() - 5));
  EXPECT_EQ(cut.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(cut.problem, "PixelData (7FE0,0010): the file is cut short: expected 24 bytes of pixel data, found 19")) << cut.problem;
}

TEST(DicomScan, MalformedElementsNameTheByteAndTag) {
  DicomDataSet bad_vr;
  bad_vr.raw(std::string("\x08\x00\x60\x00" "zz" "\x02\x00" "CT", 10));
  DicomScan s = scan(dicom_file(kExplicitLE, bad_vr));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "Modality (0008,0060): expected a value representation (VR)")) << s.problem;
  EXPECT_TRUE(has(s.problem, "found 'zz'")) << s.problem;
  EXPECT_TRUE(has(s.problem, "byte ")) << s.problem;

  DicomDataSet undefined_cs;
  undefined_cs.raw(std::string("\x08\x00\x60\x00" "UN" "\x00\x00\xFF\xFF\xFF\xFF", 12));
  s = scan(dicom_file(kExplicitLE, undefined_cs));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken) << "a UN of undefined length needs items";

  DicomDataSet stray_item;
  stray_item.raw(std::string("\xFE\xFF\x00\xE0\x00\x00\x00\x00", 8));
  s = scan(dicom_file(kExplicitLE, stray_item));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "item or delimiter tag")) << s.problem;

  DicomDataSet frames = ct_slice(true, false, 0, "1");
  frames.text(0x0028, 0x0008, "IS", "two");
  s = scan(dicom_file(kExplicitLE, frames));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "NumberOfFrames (0028,0008): expected an integer, found 'two'")) << s.problem;

  EXPECT_EQ(scan(dicom_file("", ct_slice(true, false, 0, "1"))).status, DicomScanStatus::kBroken);
  const DicomScan ts = scan(dicom_file("1.2.840.10008.1.2.1.99", ct_slice(true, false, 0, "1")));
  EXPECT_EQ(ts.status, DicomScanStatus::kUnsupported);
  EXPECT_TRUE(has(ts.problem, "deflated")) << ts.problem;
}

TEST(DicomScan, PixelFormatsTheLoaderRefuses) {
  // A 3 x 4 image with field (0028,e) set to v.
  const auto with = [](std::uint16_t e, std::uint16_t v) {
    DicomDataSet out;
    out.text(0x0008, 0x0060, "CS", "CT").uid(0x0020, 0x000E, "1");
    out.us(0x0028, 0x0002, e == 0x0002 ? v : 1);
    out.us(0x0028, 0x0010, 3).us(0x0028, 0x0011, 4);
    out.us(0x0028, 0x0100, e == 0x0100 ? v : 16).us(0x0028, 0x0101, e == 0x0101 ? v : 16);
    out.us(0x0028, 0x0102, e == 0x0102 ? v : 15).us(0x0028, 0x0103, e == 0x0103 ? v : 0);
    out.pixels(96);
    return scan(dicom_file(kExplicitLE, out));
  };
  DicomScan s = with(0x0100, 32);
  EXPECT_EQ(s.status, DicomScanStatus::kUnsupported);
  EXPECT_TRUE(has(s.problem, "BitsAllocated (0028,0100): expected 8 or 16, found 32")) << s.problem;
  s = with(0x0002, 3);
  EXPECT_EQ(s.status, DicomScanStatus::kUnsupported);
  EXPECT_TRUE(has(s.problem, "SamplesPerPixel (0028,0002): expected 1")) << s.problem;
  s = with(0x0101, 20);
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "BitsStored (0028,0101)")) << s.problem;
  s = with(0x0102, 3);
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "HighBit (0028,0102): expected 15..15")) << s.problem;
  s = with(0x0103, 2);
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "PixelRepresentation (0028,0103)")) << s.problem;

  DicomDataSet multi = ct_slice(true, false, 0, "1");
  DicomDataSet m;
  m.text(0x0028, 0x0008, "IS", "30").raw(multi.bytes());
  s = scan(dicom_file(kExplicitLE, m));
  EXPECT_EQ(s.status, DicomScanStatus::kUnsupported);
  EXPECT_TRUE(has(s.problem, "multi-frame")) << s.problem;
}

TEST(DicomScan, CompressedFragments) {
  DicomDataSet d;
  d.text(0x0008, 0x0060, "CS", "CT").uid(0x0020, 0x000E, "1");
  d.us(0x0028, 0x0010, 3).us(0x0028, 0x0011, 4).us(0x0028, 0x0100, 16).us(0x0028, 0x0103, 1);
  DicomDataSet ok = d;
  ok.fragments({std::string(80, 'x')});
  DicomScan s = scan(dicom_file(kRle, ok));
  EXPECT_EQ(s.status, DicomScanStatus::kImage) << s.problem;
  EXPECT_TRUE(s.encapsulated);
  EXPECT_EQ(s.pixel_length, 80u);

  DicomDataSet native = d;
  native.pixels(24);
  s = scan(dicom_file(kRle, native));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "needs fragments")) << s.problem;

  DicomDataSet frag = d;
  frag.fragments({std::string(80, 'x')});
  s = scan(dicom_file(kExplicitLE, frag));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "is uncompressed")) << s.problem;

  DicomDataSet none = d;
  none.fragments({});
  s = scan(dicom_file(kRle, none));
  EXPECT_EQ(s.status, DicomScanStatus::kBroken);
  EXPECT_TRUE(has(s.problem, "at least one fragment")) << s.problem;
}

TEST(DicomScan, NotDicomAndNotAnImage) {
  EXPECT_EQ(scan("").status, DicomScanStatus::kNotDicom);
  EXPECT_EQ(scan(std::string(4000, 'x')).status, DicomScanStatus::kNotDicom);
  EXPECT_TRUE(has(scan(std::string(4000, 'x')).problem, "no 'DICM' marker at byte 128"));
  DicomDataSet report;
  report.text(0x0008, 0x0060, "CS", "SR").uid(0x0020, 0x000E, "7");
  const DicomScan s = scan(dicom_file(kExplicitLE, report));
  EXPECT_EQ(s.status, DicomScanStatus::kNotImage);
  EXPECT_EQ(s.series_uid, "7");
}

// Seeded random byte edits of valid files: the scan always returns, and what it calls an image
// really has its pixel data inside the file.
TEST(DicomScan, RandomMutationsNeverEscapeTheBytes) {
  std::mt19937 rng(20240611);
  const std::vector<std::string> seeds = test::slice_in_every_syntax();
  for (int n = 0; n < 20000; ++n) {
    const std::string b = test::mutate(seeds[static_cast<std::size_t>(n) % seeds.size()], rng, 4);
    const DicomScan s = scan(b);
    if (s.status == DicomScanStatus::kImage) {
      EXPECT_LE(s.pixel_offset + s.pixel_length, b.size());
      EXPECT_GE(s.pixel_length, s.frame_bytes());
    } else {
      EXPECT_FALSE(s.problem.empty());
    }
  }
}

}  // namespace
}  // namespace lancet::volume
