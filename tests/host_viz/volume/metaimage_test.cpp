// The MetaImage / raw loader: the real CT volumes in ../shared/data/volumes (dims, spacing in m,
// value range and voxel sums computed once with Python from the .raw files, LIDC2's orientation;
// the compressed LIDC2.mha equals its .mhd), synthetic files for each feature, malformed headers
// (each error names the field and line), and 3000 seeded random mutations that must never crash.

#include <zlib.h>

#include <gtest/gtest.h>

#include "shared_data.hpp"
#include "temp_files.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "volume/metaimage.hpp"

namespace lancet::volume {
namespace {

namespace fs = std::filesystem;

struct Stats {
  float min = 0, max = 0;
  double sum = 0;
};

Stats stats(const Volume& v) {
  Stats s{v.data.front(), v.data.front(), 0};
  for (float x : v.data) {
    s.min = std::min(s.min, x);
    s.max = std::max(s.max, x);
    s.sum += x;
  }
  return s;
}

struct RealCase {
  const char* file;
  std::array<int, 3> dims;
  std::array<double, 3> spacing_mm;
  VoxelType type;
  float min, max;
  double sum;  // sum of all voxel values, from Python over the .raw file
};

constexpr RealCase kReal[] = {
    {"aneurism_cta_head/aneurism_256x256x256_uint8.mhd", {256, 256, 256}, {1, 1, 1}, VoxelType::kU8, 0, 255, 17938365},
    {"chest_ct_lidc2/LIDC2_256x256x133_uint8.mhd", {256, 256, 133}, {1.40625, 1.40625, 2.5}, VoxelType::kU8, 0, 255, 61489178},
    {"foot_ct_lossy/foot_256x256x256_uint8_zfplossy.mhd", {256, 256, 256}, {1, 1, 1}, VoxelType::kU8, 0, 255, 233795338},
    {"head_ct_headsq/headsq_64x64x93_int16.mhd", {64, 64, 93}, {3.2, 3.2, 1.5}, VoxelType::kI16, 0, 3926, 193392317},
    {"tooth_ct/tooth_103x94x161_uint8.mhd", {103, 94, 161}, {1, 1, 1}, VoxelType::kU8, 0, 255, 160814065},
};

TEST(MetaImageReal, EveryMhdLoadsWithPinnedGeometryAndValues) {
  LANCET_SHARED_VOLUMES_OR_RETURN(kVolumes);
  for (const RealCase& c : kReal) {
    SCOPED_TRACE(c.file);
    int calls = 0;
    double last = -1;
    bool monotonic = true;
    auto r = load_metaimage(kVolumes + "/" + c.file, [&](double f) {
      monotonic = monotonic && f >= last && f >= 0 && f <= 1;
      last = f;
      ++calls;
    });
    ASSERT_TRUE(r.ok()) << r.error().message;
    const Volume& v = r.value();
    EXPECT_EQ(v.dims, c.dims);
    EXPECT_NEAR(v.spacing.x, c.spacing_mm[0] * 1e-3, 1e-12);
    EXPECT_NEAR(v.spacing.y, c.spacing_mm[1] * 1e-3, 1e-12);
    EXPECT_NEAR(v.spacing.z, c.spacing_mm[2] * 1e-3, 1e-12);
    EXPECT_EQ(v.source_type, c.type);
    EXPECT_EQ(v.value_unit, "raw");
    ASSERT_EQ(v.data.size(), v.voxel_count());
    const Stats s = stats(v);
    EXPECT_EQ(s.min, c.min);
    EXPECT_EQ(s.max, c.max);
    EXPECT_EQ(s.sum, c.sum);
    EXPECT_TRUE(monotonic);
    EXPECT_EQ(last, 1.0);
    EXPECT_GE(calls, 2);
    EXPECT_LE(calls, 200);  // a few dozen, never per voxel
  }
}

TEST(MetaImageReal, Lidc2OrientationAndOrigin) {
  LANCET_SHARED_VOLUMES_OR_RETURN(kVolumes);
  auto r = load_metaimage_with_info(kVolumes + "/chest_ct_lidc2/LIDC2_256x256x133_uint8.mhd");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value().volume;
  EXPECT_EQ(r.value().anatomical_orientation, "RPS");
  EXPECT_NEAR(v.origin.x, 0.0, 1e-12);
  EXPECT_NEAR(v.origin.y, 0.360, 1e-12);
  EXPECT_NEAR(v.origin.z, 0.3325, 1e-12);
  const std::array<double, 9> flip_yz{1, 0, 0, 0, -1, 0, 0, 0, -1};
  EXPECT_EQ(v.direction, flip_yz);
  // Index y and z run against world y and z: the last voxel lies below and behind the first.
  const Vec3 first = v.position(0, 0, 0);
  const Vec3 last = v.position(255, 255, 132);
  EXPECT_NEAR(last.x - first.x, 255 * 1.40625e-3, 1e-12);
  EXPECT_NEAR(last.y - first.y, -255 * 1.40625e-3, 1e-12);
  EXPECT_NEAR(last.z - first.z, -132 * 2.5e-3, 1e-12);
  EXPECT_NEAR(last.z, 0.3325 - 0.330, 1e-12);
}

TEST(MetaImageReal, CompressedLidc2MhaEqualsTheRawMhd) {
  LANCET_SHARED_VOLUMES_OR_RETURN(kVolumes);
  int calls = 0;
  auto mha = load_metaimage_with_info(kVolumes + "/chest_ct_lidc2/LIDC2.mha", [&](double) { ++calls; });
  ASSERT_TRUE(mha.ok()) << mha.error().message;
  auto mhd = load_metaimage(kVolumes + "/chest_ct_lidc2/LIDC2_256x256x133_uint8.mhd");
  ASSERT_TRUE(mhd.ok()) << mhd.error().message;
  const Volume& a = mha.value().volume;
  const Volume& b = mhd.value();
  EXPECT_EQ(a.dims, b.dims);
  EXPECT_TRUE(a.data == b.data) << "the decompressed voxels differ from the .raw file";
  EXPECT_EQ(mha.value().anatomical_orientation, "RPS");
  // The .mha carries the unrounded geometry; the .mhd rounds it.
  EXPECT_NEAR(a.spacing.x, b.spacing.x, 1e-15);
  EXPECT_NEAR(a.spacing.z, b.spacing.z, 1e-15);
  EXPECT_NEAR(a.origin.y, 0.360, 1e-15);
  EXPECT_NEAR(a.origin.z, 0.3325, 1e-15);
  for (std::size_t i = 0; i < 9; ++i) EXPECT_NEAR(a.direction[i], b.direction[i], 1e-14) << i;
  EXPECT_GE(calls, 10);
  EXPECT_LE(calls, 200);
}

// ---- synthetic files ----------------------------------------------------------------------

class MetaImageFiles : public test::TempDirTest {};

using test::bytes_of;

std::string zlib_compress(const std::string& raw) {
  uLongf n = compressBound(static_cast<uLong>(raw.size()));
  std::string out(n, '\0');
  EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(out.data()), &n, reinterpret_cast<const Bytef*>(raw.data()),
                      static_cast<uLong>(raw.size()), 9),
            Z_OK);
  out.resize(n);
  return out;
}

const std::vector<std::int16_t> kI16Values{-32768, -1, 0, 1, 300, 32767, 1234, -4321, 7, 8, 9, 10};  // 3×2×2

TEST_F(MetaImageFiles, BigEndianInt16) {
  const std::string raw = write("be.raw", bytes_of(kI16Values, true));
  const std::string mhd = write("be.mhd",
                                "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\nElementType = MET_SHORT\n"
                                "ElementByteOrderMSB = True\nElementSpacing = 0.5 0.25 2\nElementDataFile = be.raw\n");
  auto r = load_metaimage(mhd);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().source_type, VoxelType::kI16);
  ASSERT_EQ(r.value().data.size(), kI16Values.size());
  for (std::size_t i = 0; i < kI16Values.size(); ++i) EXPECT_EQ(r.value().data[i], kI16Values[i]) << i;
  EXPECT_DOUBLE_EQ(r.value().spacing.y, 0.25e-3);
  EXPECT_EQ(r.value().at(2, 1, 1), 10.0f);
  EXPECT_EQ(r.value().at(1, 1, 0), 300.0f);

  // The same file through load_raw, and a little-endian read gives the swapped values.
  auto raw_be = load_raw(raw, {3, 2, 2}, VoxelType::kI16, Vec3{1e-3, 1e-3, 1e-3}, true);
  ASSERT_TRUE(raw_be.ok()) << raw_be.error().message;
  EXPECT_EQ(raw_be.value().data, r.value().data);
  auto raw_le = load_raw(raw, {3, 2, 2}, VoxelType::kI16, Vec3{1e-3, 1e-3, 1e-3}, false);
  ASSERT_TRUE(raw_le.ok());
  EXPECT_EQ(raw_le.value().data[4], 11265.0f);  // 300 = 0x012C read as 0x2C01
}

// Values are Hounsfield units only when the header says the scan is CT.
TEST_F(MetaImageFiles, ModalitySetsTheValueUnit) {
  const std::string head = "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\nElementType = MET_SHORT\n";
  const std::string data = "ElementDataFile = LOCAL\n" + bytes_of(kI16Values, false);
  auto plain = load_metaimage(write("plain.mha", head + data));
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_EQ(plain.value().value_unit, "raw");
  EXPECT_EQ(plain.value().modality, "");
  auto ct = load_metaimage(write("ct.mha", head + "Modality = MET_MOD_CT\n" + data));
  ASSERT_TRUE(ct.ok()) << ct.error().message;
  EXPECT_EQ(ct.value().value_unit, "HU");
  EXPECT_EQ(ct.value().modality, "CT");
  auto mr = load_metaimage(write("mr.mha", head + "Modality = MET_MOD_MR\n" + data));
  ASSERT_TRUE(mr.ok()) << mr.error().message;
  EXPECT_EQ(mr.value().value_unit, "raw");
  EXPECT_EQ(mr.value().modality, "MR");
  auto bad = load_metaimage(write("bad.mha", head + "Modality = CT\n" + data));
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("bad.mha:5: Modality: expected one of MET_MOD_CT"), std::string::npos) << bad.error().message;
}

TEST_F(MetaImageFiles, Float32AndDoubleAndOtherTypes) {
  const std::vector<float> f{0.5f, -1.25f, 3e10f, 0.0f, 1.0f, -0.0f, 2.0f, 4.0f};
  write("f.raw", bytes_of(f, false));
  auto r = load_metaimage(write("f.mhd", "NDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\nElementDataFile = f.raw\n"));
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().data, f);
  EXPECT_EQ(r.value().source_type, VoxelType::kF32);
  // No spacing given: 1 mm.
  EXPECT_DOUBLE_EQ(r.value().spacing.x, 1e-3);

  const std::vector<double> d{0.5, -1.25, 1e300, 7};
  write("d.raw", bytes_of(d, true));
  auto rd = load_metaimage(write("d.mhd", "NDims = 3\nDimSize = 4 1 1\nElementType = MET_DOUBLE\n"
                                          "BinaryDataByteOrderMSB = True\nElementSize = 2 3 4\nElementDataFile = d.raw\n"));
  ASSERT_TRUE(rd.ok()) << rd.error().message;
  EXPECT_EQ(rd.value().data[1], -1.25f);
  EXPECT_EQ(rd.value().data[3], 7.0f);
  EXPECT_DOUBLE_EQ(rd.value().spacing.z, 4e-3);  // ElementSize as the fallback

  const std::vector<std::int8_t> c{-128, 127};
  write("c.raw", bytes_of(c, false));
  auto rc = load_metaimage(write("c.mhd", "NDims = 3\nDimSize = 1 2 1\nElementType = MET_CHAR\nElementDataFile = c.raw\n"));
  ASSERT_TRUE(rc.ok()) << rc.error().message;
  EXPECT_EQ(rc.value().data, (std::vector<float>{-128, 127}));
  EXPECT_EQ(rc.value().source_type, VoxelType::kI16);

  const std::vector<std::uint16_t> us{65535, 1};
  write("us.raw", bytes_of(us, false));
  auto ru = load_metaimage(write("us.mhd", "NDims = 3\nDimSize = 1 1 2\nElementType = MET_USHORT\nElementDataFile = us.raw\n"));
  ASSERT_TRUE(ru.ok()) << ru.error().message;
  EXPECT_EQ(ru.value().data, (std::vector<float>{65535, 1}));
  EXPECT_EQ(ru.value().source_type, VoxelType::kU16);

  const std::vector<std::int32_t> i32{-100000, 100000};
  write("i.raw", bytes_of(i32, true));
  auto ri = load_metaimage(write("i.mhd", "NDims = 3\nDimSize = 2 1 1\nElementType = MET_INT\nElementByteOrderMSB = True\nElementDataFile = i.raw\n"));
  ASSERT_TRUE(ri.ok()) << ri.error().message;
  EXPECT_EQ(ri.value().data, (std::vector<float>{-100000, 100000}));
  EXPECT_EQ(ri.value().source_type, VoxelType::kF32);

  const std::vector<std::uint32_t> u32{4000000000u, 3};
  write("u.raw", bytes_of(u32, false));
  auto ru32 = load_metaimage(write("u.mhd", "NDims = 3\nDimSize = 2 1 1\nElementType = MET_UINT\nElementDataFile = u.raw\n"));
  ASSERT_TRUE(ru32.ok()) << ru32.error().message;
  EXPECT_EQ(ru32.value().data, (std::vector<float>{4e9f, 3}));
}

TEST_F(MetaImageFiles, HeaderSizeSkipsBytesAndMinusOneMeansAtTheEnd) {
  const std::vector<std::uint8_t> v{1, 2, 3, 4, 5, 6, 7, 8};
  write("h.raw", std::string(100, 'X') + bytes_of(v, false));
  auto r = load_metaimage(write("h.mhd", "NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nHeaderSize = 100\nElementDataFile = h.raw\n"));
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().data, (std::vector<float>{1, 2, 3, 4, 5, 6, 7, 8}));
  auto e = load_metaimage(write("e.mhd", "NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nHeaderSize = -1\nElementDataFile = h.raw\n"));
  ASSERT_TRUE(e.ok()) << e.error().message;
  EXPECT_EQ(e.value().data, r.value().data);
  auto wrong = load_metaimage(write("w.mhd", "NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nHeaderSize = 99\nElementDataFile = h.raw\n"));
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().message.find("expected 8 bytes"), std::string::npos) << wrong.error().message;
  EXPECT_NE(wrong.error().message.find("found 9"), std::string::npos) << wrong.error().message;
}

std::string kSmallHeader(const std::string& extra = "") {
  return "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\nElementType = MET_SHORT\nElementSpacing = 1 2 3\n"
         "Offset = 10 20 30\nTransformMatrix = 0 1 0 -1 0 0 0 0 1\n" + extra;
}

TEST_F(MetaImageFiles, MhaWithLocalRawAndCompressedData) {
  const std::string data = bytes_of(kI16Values, false);
  auto r = load_metaimage_with_info(write("raw.mha", kSmallHeader("AnatomicalOrientation = LPS\r\nElementDataFile = LOCAL\n") + data));
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value().volume;
  EXPECT_EQ(r.value().anatomical_orientation, "LPS");
  for (std::size_t i = 0; i < kI16Values.size(); ++i) EXPECT_EQ(v.data[i], kI16Values[i]);
  EXPECT_NEAR(v.origin.z, 0.030, 1e-15);
  // Axis 0 points along world +y, axis 1 along world -x (ITK's reading of TransformMatrix).
  const Vec3 p = v.position(1, 0, 0) - v.position(0, 0, 0);
  EXPECT_NEAR(p.y, 1e-3, 1e-15);
  EXPECT_NEAR(p.x, 0, 1e-15);
  const Vec3 q = v.position(0, 1, 0) - v.position(0, 0, 0);
  EXPECT_NEAR(q.x, -2e-3, 1e-15);

  const std::string z = zlib_compress(data);
  auto c = load_metaimage(write("z.mha", kSmallHeader("CompressedData = True\nCompressedDataSize = " +
                                                      std::to_string(z.size()) + "\nElementDataFile = LOCAL\n") + z));
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c.value().data, v.data);
  // Without CompressedDataSize the stream runs to the end of the file.
  auto c2 = load_metaimage(write("z2.mha", kSmallHeader("CompressedData = True\nElementDataFile = LOCAL\n") + z));
  ASSERT_TRUE(c2.ok()) << c2.error().message;
  EXPECT_EQ(c2.value().data, v.data);
  // A detached compressed file.
  write("z.zraw", z);
  auto c3 = load_metaimage(write("z.mhd", kSmallHeader("CompressedData = True\nElementDataFile = z.zraw\n")));
  ASSERT_TRUE(c3.ok()) << c3.error().message;
  EXPECT_EQ(c3.value().data, v.data);
}

TEST_F(MetaImageFiles, TwoDimensionsAndChannelsAreRefusedClearly) {
  auto two = load_metaimage(write("2d.mha", "ObjectType = Image\nNDims = 2\nDimSize = 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\nabcd"));
  ASSERT_FALSE(two.ok());
  EXPECT_NE(two.error().message.find(":2: NDims"), std::string::npos) << two.error().message;
  EXPECT_NE(two.error().message.find("2-D"), std::string::npos) << two.error().message;
  auto ch = load_metaimage(write("ch.mha", "NDims = 3\nDimSize = 1 1 1\nElementNumberOfChannels = 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\nabc"));
  ASSERT_FALSE(ch.ok());
  EXPECT_NE(ch.error().message.find(":3: ElementNumberOfChannels"), std::string::npos) << ch.error().message;
  EXPECT_NE(ch.error().message.find("found '3'"), std::string::npos) << ch.error().message;
}

struct Bad {
  const char* header;  // with the 12 bytes of 3×2×2 MET_UCHAR data (or the compressed stream) after it
  const char* expect;  // substrings the message must contain (separated by '|')
};

TEST_F(MetaImageFiles, MalformedHeadersNameTheFieldAndLine) {
  const std::string data(12, '\x05');
  const Bad cases[] = {
      {"NDims = 3\nDimSize = 3 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":2: DimSize|found '3 2'"},
      {"NDims = 3\nDimSize = 3 0 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":2: DimSize"},
      {"NDims = 3\nDimSize = 3 -2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":2: DimSize"},
      {"NDims = 3\nDimSize = 3 2 x\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":2: DimSize"},
      {"NDims = 3\nDimSize = 65536 65536 65536\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":2: DimSize|2147483648"},
      {"NDims = 3\nDimSize = 99999999999 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":2: DimSize"},
      {"NDims = 3\n\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementSpacing = 1 nan 1\nElementDataFile = LOCAL\n", ":5: ElementSpacing|positive finite"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementSpacing = 1 0 1\nElementDataFile = LOCAL\n", ":4: ElementSpacing"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementSpacing = 1 -1 1\nElementDataFile = LOCAL\n", ":4: ElementSpacing"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementSpacing = 1 1\nElementDataFile = LOCAL\n", ":4: ElementSpacing|3 positive"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementSize = inf 1 1\nElementDataFile = LOCAL\n", ":4: ElementSize"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_BIG\nElementDataFile = LOCAL\n", ":3: ElementType|MET_BIG|MET_UCHAR"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_SHORT\nElementDataFile = LOCAL\n", "expected 24 bytes|found 12"},
      {"NDims = 3\nDimSize = 3 2 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", "expected 18 bytes|found 12"},
      {"NDims = 3\nDimSize = 3 2 1\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", "expected 6 bytes|found 12"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = missing.raw\n", "ElementDataFile|missing.raw|not found"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = LIST\n", ":4: ElementDataFile|file lists"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = slice%03d.raw 1 2 1\n", ":4: ElementDataFile"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = \n", ":4: ElementDataFile"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\n", ":4:|ElementDataFile"},
      {"DimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", "NDims|found none"},
      {"NDims = 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", "DimSize|found none"},
      {"NDims = 3\nDimSize = 3 2 2\nElementDataFile = LOCAL\n", "ElementType|found none"},
      {"NDims = three\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":1: NDims|'three'"},
      {"ObjectType = Mesh\nNDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n", ":1: ObjectType|Image|'Mesh'"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nBinaryData = False\nElementDataFile = LOCAL\n", ":4: BinaryData|ASCII"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementByteOrderMSB = maybe\nElementDataFile = LOCAL\n", ":4: ElementByteOrderMSB|True or False"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nOffset = 1 2\nElementDataFile = LOCAL\n", ":4: Offset"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nTransformMatrix = 1 0 0 0 1 0 0 0\nElementDataFile = LOCAL\n", ":4: TransformMatrix|9 finite"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nTransformMatrix = 1 0 0 1 0 0 0 0 1\nElementDataFile = LOCAL\n", ":4: TransformMatrix|invertible"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nHeaderSize = -2\nElementDataFile = LOCAL\n", ":4: HeaderSize|-1.."},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nHeaderSize = 100\nElementDataFile = LOCAL\n", "HeaderSize|found 100"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nCompressedData = True\nElementDataFile = LOCAL\n", "CompressedData|corrupt zlib"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nCompressedData = True\nCompressedDataSize = 99999999\nElementDataFile = LOCAL\n", ":5: CompressedDataSize|99999999"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nCompressedData = True\nCompressedDataSize = 20\nElementDataFile = LOCAL\n", "CompressedDataSize|at most the 12 bytes|found 20"},
      {"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nthis line has no equals sign\nElementDataFile = LOCAL\n", ":4:|Key = value"},
  };
  int n = 0;
  for (const Bad& b : cases) {
    SCOPED_TRACE(b.header);
    const std::string p = write("bad" + std::to_string(n++) + ".mha", std::string(b.header) + data);
    auto r = load_metaimage(p);
    ASSERT_FALSE(r.ok());
    const std::string& m = r.error().message;
    EXPECT_NE(m.find(p), std::string::npos) << m;
    std::string want = b.expect;
    std::size_t start = 0;
    while (start <= want.size()) {
      const std::size_t bar = std::min(want.find('|', start), want.size());
      EXPECT_NE(m.find(want.substr(start, bar - start)), std::string::npos) << "missing '" << want.substr(start, bar - start) << "' in: " << m;
      start = bar + 1;
    }
  }
}

TEST_F(MetaImageFiles, CompressedStreamsTooShortTooLongOrCorrupt) {
  const std::string data = bytes_of(kI16Values, false);
  const std::string z = zlib_compress(data);
  const std::string head = kSmallHeader("CompressedData = True\nElementDataFile = LOCAL\n");
  auto truncated = load_metaimage(write("t.mha", head + z.substr(0, z.size() / 2)));
  ASSERT_FALSE(truncated.ok());
  EXPECT_NE(truncated.error().message.find("CompressedData"), std::string::npos) << truncated.error().message;

  auto too_long = load_metaimage(write("l.mha", head + zlib_compress(data + data)));
  ASSERT_FALSE(too_long.ok());
  EXPECT_NE(too_long.error().message.find("more than the expected 24 bytes"), std::string::npos) << too_long.error().message;

  auto too_short = load_metaimage(write("s.mha", head + zlib_compress(data.substr(0, 20))));
  ASSERT_FALSE(too_short.ok());
  EXPECT_NE(too_short.error().message.find("expected 24 bytes (DimSize × element size), found 20"), std::string::npos)
      << too_short.error().message;

  std::string corrupt = z;
  corrupt[4] = static_cast<char>(corrupt[4] ^ 0x55);
  corrupt[5] = static_cast<char>(corrupt[5] ^ 0xAA);
  auto bad = load_metaimage(write("c.mha", head + corrupt));
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("CompressedData"), std::string::npos) << bad.error().message;
}

TEST_F(MetaImageFiles, LoadRawChecksItsArguments) {
  const std::string p = write("r.raw", std::string(12, '\x01'));
  auto ok = load_raw(p, {3, 2, 2}, VoxelType::kU8, Vec3{1e-3, 2e-3, 3e-3});
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok.value().data, std::vector<float>(12, 1.0f));
  EXPECT_EQ(ok.value().spacing.z, 3e-3);
  auto size = load_raw(p, {3, 2, 2}, VoxelType::kU16, Vec3{1e-3, 1e-3, 1e-3});
  ASSERT_FALSE(size.ok());
  EXPECT_NE(size.error().message.find("expected 24 bytes"), std::string::npos) << size.error().message;
  EXPECT_NE(size.error().message.find("found 12"), std::string::npos) << size.error().message;
  EXPECT_FALSE(load_raw(p, {3, 0, 2}, VoxelType::kU8, Vec3{1e-3, 1e-3, 1e-3}).ok());
  EXPECT_FALSE(load_raw(p, {65536, 65536, 1024}, VoxelType::kU8, Vec3{1e-3, 1e-3, 1e-3}).ok());
  EXPECT_FALSE(load_raw(p, {3, 2, 2}, VoxelType::kU8, Vec3{1e-3, std::nan(""), 1e-3}).ok());
  EXPECT_FALSE(load_raw(p, {3, 2, 2}, VoxelType::kU8, Vec3{1e-3, 0, 1e-3}).ok());
  auto missing = load_raw((dir_ / "nope.raw").string(), {3, 2, 2}, VoxelType::kU8, Vec3{1e-3, 1e-3, 1e-3});
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  auto missing_mhd = load_metaimage((dir_ / "nope.mhd").string());
  ASSERT_FALSE(missing_mhd.ok());
  EXPECT_EQ(missing_mhd.error().code, ErrorCode::kNotFound);
  auto dir = load_metaimage(dir_.string());
  EXPECT_FALSE(dir.ok());
}

// ---- robustness -----------------------------------------------------------------------------

std::string mutate(std::string s, std::mt19937& rng) {
  auto pick = [&](std::size_t n) { return n == 0 ? std::size_t{0} : std::uniform_int_distribution<std::size_t>(0, n - 1)(rng); };
  static const char* kHuge[] = {"99999999999999999999", "2147483647", "-2147483648", "4294967296", "1e308",
                                "nan", "-1", "0", "1e-320", "65536 65536 65536", "18446744073709551615"};
  const int edits = 1 + static_cast<int>(pick(4));
  for (int e = 0; e < edits; ++e) {
    switch (pick(6)) {
      case 0:  // flip a byte
        if (!s.empty()) s[pick(s.size())] = static_cast<char>(pick(256));
        break;
      case 1:  // truncate
        s.resize(pick(s.size() + 1));
        break;
      case 2:
      case 3: {  // duplicate or remove a line
        std::vector<std::string> lines;
        std::size_t p = 0;
        while (p < s.size()) {
          const std::size_t nl = s.find('\n', p);
          const std::size_t end = nl == std::string::npos ? s.size() : nl + 1;
          lines.push_back(s.substr(p, end - p));
          p = end;
        }
        if (lines.empty()) break;
        const std::size_t i = pick(std::min<std::size_t>(lines.size(), 12));
        if (i < lines.size()) {
          if (e % 2 == 0) lines.insert(lines.begin() + static_cast<std::ptrdiff_t>(pick(lines.size())), lines[i]);
          else lines.erase(lines.begin() + static_cast<std::ptrdiff_t>(i));
        }
        s.clear();
        for (const auto& l : lines) s += l;
        break;
      }
      case 4: {  // replace a number in the header with a huge or odd one
        const std::size_t header_end = std::min(s.size(), s.find("LOCAL") == std::string::npos ? s.size() : s.find("LOCAL"));
        std::size_t at = pick(header_end);
        while (at < header_end && !(s[at] >= '0' && s[at] <= '9')) ++at;
        if (at >= header_end) break;
        std::size_t end = at;
        while (end < s.size() && ((s[end] >= '0' && s[end] <= '9') || s[end] == '.')) ++end;
        s.replace(at, end - at, kHuge[pick(std::size(kHuge))]);
        break;
      }
      default:  // append junk
        s += std::string(pick(40), static_cast<char>(pick(256)));
        break;
    }
  }
  return s;
}

TEST_F(MetaImageFiles, RandomMutationsNeverCrash) {
  const std::string data = bytes_of(kI16Values, false);
  const std::string z = zlib_compress(data);
  const std::string seeds[] = {
      kSmallHeader("ElementDataFile = LOCAL\n") + data,
      kSmallHeader("CompressedData = True\nCompressedDataSize = " + std::to_string(z.size()) + "\nElementDataFile = LOCAL\n") + z,
      "NDims = 3\nDimSize = 2 3 2\nElementType = MET_SHORT\nElementByteOrderMSB = True\nHeaderSize = 2\nElementDataFile = LOCAL\n\xff\xff" +
          bytes_of(kI16Values, true),
  };
  std::mt19937 rng(20240611);
  int ok = 0, errors = 0;
  for (int i = 0; i < 3000; ++i) {
    const std::string bytes = mutate(seeds[static_cast<std::size_t>(i) % std::size(seeds)], rng);
    const std::string p = write("m.mha", bytes);
    auto r = load_metaimage(p);
    if (r.ok()) {
      ++ok;
      const Volume& v = r.value();
      ASSERT_EQ(v.data.size(), v.voxel_count()) << "mutation " << i;
      ASSERT_GT(v.spacing.x, 0);
      ASSERT_TRUE(is_finite(v.origin));
    } else {
      ++errors;
      ASSERT_FALSE(r.error().message.empty());
      ASSERT_NE(r.error().message.find(p), std::string::npos) << r.error().message;
    }
  }
  // Both outcomes occur: the mutations are neither all harmless nor all fatal.
  EXPECT_GT(ok, 100);
  EXPECT_GT(errors, 100);
}

}  // namespace
}  // namespace lancet::volume
