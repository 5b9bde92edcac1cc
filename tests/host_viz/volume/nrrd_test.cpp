// The NRRD loader: the real headsq quarter.nhdr (detached, pattern list of 93 int16 slices) and
// tooth.nrrd (attached, raw) against their MetaImage twins voxel for voxel; synthetic files for
// gzip, big endian, LIST, byte/line skip, space directions + origin; malformed headers (each error
// names the field and line); and 2000 seeded random mutations that must never crash.

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
#include "volume/nrrd.hpp"

namespace lancet::volume {
namespace {

namespace fs = std::filesystem;

TEST(NrrdReal, HeadsqPatternListEqualsTheConcatenatedRaw) {
  LANCET_SHARED_VOLUMES_OR_RETURN(kVolumes);
  int calls = 0;
  double last = -1;
  bool monotonic = true;
  auto n = load_nrrd(kVolumes + "/head_ct_headsq/original/quarter.nhdr", [&](double f) {
    monotonic = monotonic && f >= last && f >= 0 && f <= 1;
    last = f;
    ++calls;
  });
  ASSERT_TRUE(n.ok()) << n.error().message;
  auto m = load_metaimage(kVolumes + "/head_ct_headsq/headsq_64x64x93_int16.mhd");
  ASSERT_TRUE(m.ok()) << m.error().message;
  const Volume& v = n.value();
  EXPECT_EQ(v.dims, (std::array<int, 3>{64, 64, 93}));
  EXPECT_EQ(v.source_type, VoxelType::kI16);
  // The header's own values: spacings 3.2 3.2 1.5 (mm), endian little, no origin.
  EXPECT_DOUBLE_EQ(v.spacing.x, 3.2e-3);
  EXPECT_DOUBLE_EQ(v.spacing.y, 3.2e-3);
  EXPECT_DOUBLE_EQ(v.spacing.z, 1.5e-3);
  EXPECT_EQ(v.origin.x, 0.0);
  EXPECT_EQ(v.direction, (std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1}));
  ASSERT_EQ(v.data.size(), m.value().data.size());
  EXPECT_TRUE(v.data == m.value().data);  // voxel for voxel
  EXPECT_EQ(*std::max_element(v.data.begin(), v.data.end()), 3926.0f);  // little endian read as such
  EXPECT_TRUE(monotonic);
  EXPECT_GE(calls, 10);
  EXPECT_LE(calls, 300);
  EXPECT_DOUBLE_EQ(last, 1.0);
}

TEST(NrrdReal, ToothAttachedEqualsTheMhd) {
  LANCET_SHARED_VOLUMES_OR_RETURN(kVolumes);
  auto n = load_nrrd(kVolumes + "/tooth_ct/tooth.nrrd");
  ASSERT_TRUE(n.ok()) << n.error().message;
  auto m = load_metaimage(kVolumes + "/tooth_ct/tooth_103x94x161_uint8.mhd");
  ASSERT_TRUE(m.ok()) << m.error().message;
  const Volume& v = n.value();
  EXPECT_EQ(v.dims, (std::array<int, 3>{103, 94, 161}));
  EXPECT_EQ(v.source_type, VoxelType::kU8);
  EXPECT_DOUBLE_EQ(v.spacing.x, 1e-3);
  EXPECT_DOUBLE_EQ(v.spacing.z, 1e-3);
  EXPECT_EQ(v.direction, (std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1}));
  EXPECT_TRUE(v.data == m.value().data);
}

// ---- synthetic files ----------------------------------------------------------------------

class NrrdFiles : public test::TempDirTest {};

using test::bytes_of;

std::string gzip_compress(const std::string& raw) {
  z_stream zs{};
  EXPECT_EQ(deflateInit2(&zs, 9, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY), Z_OK);
  std::string out(deflateBound(&zs, static_cast<uLong>(raw.size())) + 32, '\0');
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(raw.data()));
  zs.avail_in = static_cast<uInt>(raw.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(deflate(&zs, Z_FINISH), Z_STREAM_END);
  out.resize(zs.total_out);
  deflateEnd(&zs);
  return out;
}

const std::vector<std::int16_t> kI16Values{-32768, -1, 0, 1, 300, 32767, 1234, -4321, 7, 8, 9, 10};  // 3×2×2

std::vector<float> as_floats(const std::vector<std::int16_t>& v) { return {v.begin(), v.end()}; }

std::string small_header(const std::string& extra) {
  return "NRRD0004\n# a comment\ntype: short\ndimension: 3\nsizes: 3 2 2\nendian: little\nmy key:=my value\n" + extra;
}

TEST_F(NrrdFiles, GzipAttachedAndDetached) {
  const std::string z = gzip_compress(bytes_of(kI16Values, false));
  auto a = load_nrrd(write("a.nrrd", small_header("encoding: gzip\n\n") + z));
  ASSERT_TRUE(a.ok()) << a.error().message;
  EXPECT_EQ(a.value().data, as_floats(kI16Values));
  write("d.raw.gz", z);
  auto d = load_nrrd(write("d.nhdr", small_header("encoding: gz\ndata file: d.raw.gz\n")));
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_EQ(d.value().data, as_floats(kI16Values));
  // byte skip applies to the inflated stream.
  auto s = load_nrrd(write("s.nrrd", small_header("encoding: gzip\nbyte skip: 3\n\n") +
                                         gzip_compress("abc" + bytes_of(kI16Values, false))));
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s.value().data, as_floats(kI16Values));
  // Too short, too long, corrupt.
  const std::string head = small_header("encoding: gzip\n\n");
  auto shorter = load_nrrd(write("t.nrrd", head + gzip_compress(bytes_of(kI16Values, false).substr(0, 20))));
  ASSERT_FALSE(shorter.ok());
  EXPECT_NE(shorter.error().message.find("expected 24 bytes"), std::string::npos) << shorter.error().message;
  EXPECT_NE(shorter.error().message.find("found 20"), std::string::npos) << shorter.error().message;
  auto longer = load_nrrd(write("l.nrrd", head + gzip_compress(bytes_of(kI16Values, false) + "xx")));
  ASSERT_FALSE(longer.ok());
  EXPECT_NE(longer.error().message.find("more than the expected 24"), std::string::npos) << longer.error().message;
  std::string bad = z;
  bad[12] = static_cast<char>(bad[12] ^ 0x55);
  bad[13] = static_cast<char>(bad[13] ^ 0xAA);
  auto corrupt = load_nrrd(write("c.nrrd", head + bad));
  ASSERT_FALSE(corrupt.ok());
  EXPECT_NE(corrupt.error().message.find("encoding"), std::string::npos) << corrupt.error().message;
}

TEST_F(NrrdFiles, BigEndianAndOtherTypes) {
  auto b = load_nrrd(write("b.nrrd", "NRRD0005\ntype: int16\ndimension: 3\nsizes: 3 2 2\nendian: big\nencoding: raw\n\n" +
                                         bytes_of(kI16Values, true)));
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_EQ(b.value().data, as_floats(kI16Values));
  EXPECT_EQ(b.value().source_type, VoxelType::kI16);

  const std::vector<float> f{1.5f, -2.25f, 1e30f, 0, 3, 4, 5, 6};
  auto fl = load_nrrd(write("f.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nendian: big\nencoding: raw\n\n" +
                                          bytes_of(f, true)));
  ASSERT_TRUE(fl.ok()) << fl.error().message;
  EXPECT_EQ(fl.value().data, f);
  EXPECT_EQ(fl.value().source_type, VoxelType::kF32);

  const std::vector<double> dbl{1.5, -2.25, 7, 0, 3, 4, 5, 6};
  auto db = load_nrrd(write("d.nrrd", "NRRD0004\ntype: double\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\n\n" +
                                          bytes_of(dbl, false)));
  ASSERT_TRUE(db.ok()) << db.error().message;
  EXPECT_EQ(db.value().data, (std::vector<float>{1.5f, -2.25f, 7, 0, 3, 4, 5, 6}));

  const std::vector<std::uint16_t> us{0, 1, 65535, 40000, 5, 6, 7, 8};
  auto u = load_nrrd(write("u.nrrd", "NRRD0004\ntype: unsigned short\ndimension: 3\nsizes: 2 2 2\nendian: big\nencoding: raw\n\n" +
                                         bytes_of(us, true)));
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ(u.value().data, (std::vector<float>{0, 1, 65535, 40000, 5, 6, 7, 8}));
  EXPECT_EQ(u.value().source_type, VoxelType::kU16);

  const std::vector<std::int32_t> in{-100000, 1, 2, 3, 4, 5, 6, 7};
  auto i = load_nrrd(write("i.nrrd", "NRRD0004\ntype: int32_t\ndimension: 3\nsizes: 2 2 2\nendian: big\nencoding: raw\n\n" +
                                         bytes_of(in, true)));
  ASSERT_TRUE(i.ok()) << i.error().message;
  EXPECT_EQ(i.value().data[0], -100000.0f);

  auto s8 = load_nrrd(write("s8.nrrd", "NRRD0001\ntype: signed char\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n" +
                                           std::string("\xff\x01\x80\x7f\x00\x02\x03\x04", 8)));
  ASSERT_TRUE(s8.ok()) << s8.error().message;  // no endian needed for 1-byte types
  EXPECT_EQ(s8.value().data, (std::vector<float>{-1, 1, -128, 127, 0, 2, 3, 4}));
}

TEST_F(NrrdFiles, ListAndPatternDataFiles) {
  const std::string all = bytes_of(kI16Values, false);
  write("s0.raw", all.substr(0, 12));
  write("s1.raw", all.substr(12, 12));
  auto l = load_nrrd(write("l.nhdr", small_header("encoding: raw\ndata file: LIST\ns0.raw\ns1.raw\n")));
  ASSERT_TRUE(l.ok()) << l.error().message;
  EXPECT_EQ(l.value().data, as_floats(kI16Values));
  // subdim 1: one row (3 values) per file, 4 files.
  for (int r = 0; r < 4; ++r) write("row" + std::to_string(r) + ".raw", all.substr(static_cast<std::size_t>(r) * 6, 6));
  auto l1 = load_nrrd(write("l1.nhdr", small_header("encoding: raw\ndata file: LIST 1\nrow0.raw\nrow1.raw\nrow2.raw\nrow3.raw\n")));
  ASSERT_TRUE(l1.ok()) << l1.error().message;
  EXPECT_EQ(l1.value().data, as_floats(kI16Values));
  // Pattern with a zero-padded width and a downward step.
  write("p007.raw", all.substr(0, 12));
  write("p005.raw", all.substr(12, 12));
  auto p = load_nrrd(write("p.nhdr", small_header("encoding: raw\ndata file: p%03d.raw 7 5 -2\n")));
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_EQ(p.value().data, as_floats(kI16Values));
  // Wrong file count; missing file names its header line.
  auto count = load_nrrd(write("c.nhdr", small_header("encoding: raw\ndata file: p%03d.raw 5 9 2\n")));
  ASSERT_FALSE(count.ok());
  EXPECT_NE(count.error().message.find(":9: data file: expected 2 data files"), std::string::npos) << count.error().message;
  auto missing = load_nrrd(write("m.nhdr", small_header("encoding: raw\ndata file: LIST\ns0.raw\nnope.raw\n")));
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find(":11: data file:"), std::string::npos) << missing.error().message;
  EXPECT_NE(missing.error().message.find("nope.raw"), std::string::npos) << missing.error().message;
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
}

TEST_F(NrrdFiles, ByteSkipLineSkipAndMinusOne) {
  const std::string data = bytes_of(kI16Values, false);
  write("b.raw", "HEADER" + data);
  auto b = load_nrrd(write("b.nhdr", small_header("encoding: raw\nbyte skip: 6\ndata file: b.raw\n")));
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_EQ(b.value().data, as_floats(kI16Values));
  write("e.raw", "some junk of any length" + data);
  auto e = load_nrrd(write("e.nhdr", small_header("encoding: raw\nbyte skip: -1\ndata file: e.raw\n")));
  ASSERT_TRUE(e.ok()) << e.error().message;
  EXPECT_EQ(e.value().data, as_floats(kI16Values));
  write("ls.raw", "line one\nline two\nXY" + data);
  auto ls = load_nrrd(write("ls.nhdr", small_header("encoding: raw\nline skip: 2\nbyte skip: 2\ndata file: ls.raw\n")));
  ASSERT_TRUE(ls.ok()) << ls.error().message;
  EXPECT_EQ(ls.value().data, as_floats(kI16Values));
  auto few = load_nrrd(write("few.nhdr", small_header("encoding: raw\nline skip: 5\ndata file: ls.raw\n")));
  ASSERT_FALSE(few.ok());
  EXPECT_NE(few.error().message.find("line skip"), std::string::npos) << few.error().message;
  auto far = load_nrrd(write("far.nhdr", small_header("encoding: raw\nbyte skip: 1000\ndata file: b.raw\n")));
  ASSERT_FALSE(far.ok());
  EXPECT_NE(far.error().message.find("byte skip: expected at most 30 bytes to skip, found 1000"), std::string::npos)
      << far.error().message;
}

TEST_F(NrrdFiles, SpaceDirectionsAndOrigin) {
  auto r = load_nrrd(write("s.nrrd", small_header("encoding: raw\nspace: left-posterior-superior\n"
                                                  "space directions: (0,2,0) (-0.5, 0, 0) (0,0,3)\n"
                                                  "space origin: (10,-20,30.5)\nkinds: domain domain domain\n\n") +
                                         bytes_of(kI16Values, false)));
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value();
  EXPECT_DOUBLE_EQ(v.spacing.x, 2e-3);
  EXPECT_DOUBLE_EQ(v.spacing.y, 0.5e-3);
  EXPECT_DOUBLE_EQ(v.spacing.z, 3e-3);
  EXPECT_EQ(v.direction, (std::array<double, 9>{0, -1, 0, 1, 0, 0, 0, 0, 1}));
  EXPECT_DOUBLE_EQ(v.origin.x, 0.010);
  EXPECT_DOUBLE_EQ(v.origin.y, -0.020);
  EXPECT_DOUBLE_EQ(v.origin.z, 0.0305);
  // position() reproduces the file's index → world map: origin + i·dir0 + j·dir1 + k·dir2 (mm → m).
  const Vec3 p = v.position(1, 1, 1);
  EXPECT_NEAR(p.x, (10 + 0 - 0.5 + 0) * 1e-3, 1e-12);
  EXPECT_NEAR(p.y, (-20 + 2 + 0 + 0) * 1e-3, 1e-12);
  EXPECT_NEAR(p.z, (30.5 + 3) * 1e-3, 1e-12);
}

// pynrrd (nrrd.write with a 'space directions' entry but no 'space') writes this header: teem
// refuses it, 3D Slicer users hit it. It loads, with a warning that the space dimension was taken
// from the vectors.
TEST_F(NrrdFiles, PynrrdSpaceDirectionsWithoutSpaceLoadWithAWarning) {
  const std::string header =
      "NRRD0004\n# This NRRD file was generated by pynrrd\n# on 2024-06-11 10:00:00(GMT).\n# Complete NRRD file format "
      "specification at:\n# http://teem.sourceforge.net/nrrd/format.html\ntype: int16\ndimension: 3\n"
      "space directions: (0.5,0,0) (0,0.5,0) (0,0,2)\nsizes: 3 2 2\nkinds: domain domain domain\nendian: little\n"
      "encoding: raw\nspace origin: (-10,-20,30)\n\n";
  const std::string path = write("pynrrd.nrrd", header + bytes_of(kI16Values, false));
  auto r = load_nrrd(path);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value();
  EXPECT_DOUBLE_EQ(v.spacing.x, 0.5e-3);
  EXPECT_DOUBLE_EQ(v.spacing.z, 2e-3);
  EXPECT_DOUBLE_EQ(v.origin.x, -0.010);
  EXPECT_EQ(v.data, as_floats(kI16Values));
  ASSERT_EQ(v.warnings.size(), 1u);
  const std::string& w = v.warnings[0];
  EXPECT_NE(w.find(path + ":8: space directions: no 'space:' or 'space dimension:' line"), std::string::npos) << w;
  EXPECT_NE(w.find("took 'space dimension: 3' from its vectors of 3 numbers"), std::string::npos) << w;
  // Only an origin, no directions: inferred the same way, named on the origin's line.
  auto o = load_nrrd(write("origin.nrrd", small_header("encoding: raw\nspace origin: (1,2,3)\n\n") + bytes_of(kI16Values, false)));
  ASSERT_TRUE(o.ok()) << o.error().message;
  ASSERT_EQ(o.value().warnings.size(), 1u);
  EXPECT_NE(o.value().warnings[0].find(":9: space origin: no 'space:'"), std::string::npos) << o.value().warnings[0];
  // With a space line there is nothing to warn about.
  auto plain = load_nrrd(write("lps.nrrd", small_header("encoding: raw\nspace: LPS\nspace origin: (1,2,3)\n\n") + bytes_of(kI16Values, false)));
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_TRUE(plain.value().warnings.empty());
}

struct Bad {
  const char* header;  // followed by 24 bytes of 3×2×2 int16 data
  const char* expect;  // substrings the message must contain (separated by '|')
};

TEST_F(NrrdFiles, MalformedHeadersNameTheFieldAndLine) {
  const std::string data = bytes_of(kI16Values, false);
  const std::string T = "NRRD0004\ntype: short\ndimension: 3\nsizes: 3 2 2\nendian: little\n";  // lines 1..5
  const std::string cases_storage[][2] = {
      {"NRRD0009\n", ":1: expected the magic|'NRRD0009'"},
      {"P5 3 2\n", ":1:|NRRD0001"},
      {"NRRD0004\ntype: short\ndimension: 2\nsizes: 3 2\nendian: little\nencoding: raw\n\n", ":3: dimension|expected 3|'2'"},
      {"NRRD0004\ntype: short\ndimension: x\nsizes: 3 2 2\nendian: little\nencoding: raw\n\n", ":3: dimension|'x'"},
      {"NRRD0004\ntype: short\ndimension: 3\nsizes: 3 2\nendian: little\nencoding: raw\n\n", ":4: sizes|found '3 2'"},
      {"NRRD0004\ntype: short\ndimension: 3\nsizes: 3 0 2\nendian: little\nencoding: raw\n\n", ":4: sizes"},
      {"NRRD0004\ntype: short\ndimension: 3\nsizes: 65536 65536 65536\nendian: little\nencoding: raw\n\n", ":4: sizes|2147483648"},
      {"NRRD0004\ntype: short\ndimension: 3\nsizes: 99999999999 2 2\nendian: little\nencoding: raw\n\n", ":4: sizes"},
      {"NRRD0004\ntype: longlong\ndimension: 3\nsizes: 3 2 2\nendian: little\nencoding: raw\n\n", ":2: type|'longlong'|uchar"},
      {"NRRD0004\ntype: block\nblock size: 2\ndimension: 3\nsizes: 3 2 2\nendian: little\nencoding: raw\n\n", ":2: type|'block'"},
      {T + "encoding: ascii\n\n", ":6: encoding|raw, gzip|'ascii'"},
      {T + "encoding: bzip2\n\n", ":6: encoding|'bzip2'"},
      {"NRRD0004\ntype: short\ndimension: 3\nsizes: 3 2 2\nencoding: raw\n\n", "endian: expected a line|found none"},
      {"NRRD0004\ntype: short\ndimension: 3\nsizes: 3 2 2\nendian: middle\nencoding: raw\n\n", ":5: endian|little or big|'middle'"},
      {"NRRD0004\ndimension: 3\nsizes: 3 2 2\nendian: little\nencoding: raw\n\n", "type: expected a line|found none"},
      {"NRRD0004\ntype: short\nsizes: 3 2 2\nendian: little\nencoding: raw\n\n", "dimension: expected a line|found none"},
      {"NRRD0004\ntype: short\ndimension: 3\nendian: little\nencoding: raw\n\n", "sizes: expected a line|found none"},
      {T + "\n", "encoding: expected a line|found none"},
      {T + "encoding: raw\nspacings: 1 nan 1\n\n", ":7: spacings|positive finite"},
      {T + "encoding: raw\nspacings: 1 -1 1\n\n", ":7: spacings"},
      {T + "encoding: raw\nspacings: 1 1\n\n", ":7: spacings|3 positive"},
      {T + "encoding: raw\nspace: RAS\nspacings: 1 1 1\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n\n", ":8: spacings|not both"},
      {T + "encoding: raw\nspace: RAS\nspace directions: (1,0,0) (0,1,0)\n\n", ":8: space directions|3 vectors"},
      {T + "encoding: raw\nspace: RAS\nspace directions: (1,0,0) (0,1,0) (1,0,0)\n\n", ":8: space directions|linearly independent"},
      {T + "encoding: raw\nspace: RAS\nspace directions: (1,0,0) (0,1,0) none\n\n", ":8: space directions"},
      {T + "encoding: raw\nspace: RAS\nspace origin: (1,2)\n\n", ":8: space origin|(x,y,z)"},
      {T + "encoding: raw\nspace: right-anterior\n\n", ":7: space|3-D space|'right-anterior'"},
      {T + "encoding: raw\nspace units: \"cm\" \"cm\" \"cm\"\n\n", ":7: space units|mm"},
      {T + "encoding: raw\nbyte skip: -2\n\n", ":7: byte skip|-1.."},
      {T + "encoding: gzip\nbyte skip: -1\n\n", ":7: byte skip|-1 is only for raw"},
      {T + "encoding: raw\nline skip: -1\n\n", ":7: line skip"},
      {T + "encoding: raw\nbyte skip: 100\n\n", "byte skip|found 100"},
      {T + "encoding: raw\nsizes: 3 2 2\n\n", ":7: sizes|each field once (first on line 4)"},
      {T + "encoding: raw\nfrobnicate: yes\n\n", ":7: frobnicate|known NRRD field"},
      {T + "encoding: raw\nthis line has no colon\n\n", ":7:|field: value"},
      {T + "encoding: raw\n", "data file|blank line"},
      {T + "encoding: raw\ndata file: \n", ":7: data file|file name"},
      {T + "encoding: raw\ndata file: a b\n", ":7: data file|'a b'"},
      {T + "encoding: raw\ndata file: s%d%d.raw 1 2 1\n", ":7: data file|exactly one %d"},
      {T + "encoding: raw\ndata file: s%s.raw 1 2 1\n", ":7: data file|printf pattern"},
      {T + "encoding: raw\ndata file: s%d.raw 1 2 0\n", ":7: data file|step != 0"},
      {T + "encoding: raw\ndata file: s%d.raw 1 2 1 7\n", ":7: data file|subdim in 1..3"},
      {T + "encoding: raw\ndata file: LIST\n", ":7: data file|one file name per line"},
      {T + "encoding: raw\ndata file: missing.raw\n", ":7: data file|missing.raw|not found"},
  };
  int n = 0;
  for (const auto& c : cases_storage) {
    SCOPED_TRACE(c[0]);
    // Attached headers (ending in a blank line) get the data; detached ones stand alone.
    const bool attached = c[0].size() >= 2 && c[0].compare(c[0].size() - 2, 2, "\n\n") == 0;
    const std::string p = write("bad" + std::to_string(n++) + ".nrrd", attached ? c[0] + data : c[0]);
    auto r = load_nrrd(p);
    ASSERT_FALSE(r.ok());
    const std::string& m = r.error().message;
    EXPECT_NE(m.find(p), std::string::npos) << m;
    const std::string& want = c[1];
    std::size_t start = 0;
    while (start <= want.size()) {
      const std::size_t bar = std::min(want.find('|', start), want.size());
      EXPECT_NE(m.find(want.substr(start, bar - start)), std::string::npos) << "missing '" << want.substr(start, bar - start) << "' in: " << m;
      start = bar + 1;
    }
  }
  EXPECT_GE(n, 15);
  // Data size mismatch in both directions.
  auto more = load_nrrd(write("more.nrrd", T + "encoding: raw\n\n" + data + "x"));
  ASSERT_FALSE(more.ok());
  EXPECT_NE(more.error().message.find("expected 24 bytes"), std::string::npos) << more.error().message;
  EXPECT_NE(more.error().message.find("found 25"), std::string::npos) << more.error().message;
  auto less = load_nrrd(write("less.nrrd", T + "encoding: raw\n\n" + data.substr(0, 10)));
  ASSERT_FALSE(less.ok());
  EXPECT_NE(less.error().message.find("found 10"), std::string::npos) << less.error().message;
  auto missing = load_nrrd((dir_ / "nope.nrrd").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  EXPECT_FALSE(load_nrrd(dir_.string()).ok());
}

// ---- robustness -----------------------------------------------------------------------------

std::string mutate(std::string s, std::mt19937& rng) {
  auto pick = [&](std::size_t n) { return n == 0 ? std::size_t{0} : std::uniform_int_distribution<std::size_t>(0, n - 1)(rng); };
  static const char* kHuge[] = {"99999999999999999999", "2147483647", "-2147483648", "4294967296", "1e308",
                                "nan", "-1", "0", "1e-320", "65536 65536 65536", "18446744073709551615"};
  const int edits = 1 + static_cast<int>(pick(4));
  const std::size_t header_len = std::min(s.size(), s.find("\n\n") == std::string::npos ? s.size() : s.find("\n\n"));
  for (int e = 0; e < edits; ++e) {
    switch (pick(6)) {
      case 0:  // flip a byte
        if (!s.empty()) s[pick(s.size())] = static_cast<char>(pick(256));
        break;
      case 1:  // truncate
        s.resize(pick(s.size() + 1));
        break;
      case 2:
      case 3: {  // duplicate or remove a header line
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
        const std::size_t end_h = std::min(header_len, s.size());
        std::size_t at = pick(end_h);
        while (at < end_h && !(s[at] >= '0' && s[at] <= '9')) ++at;
        if (at >= end_h) break;
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

TEST_F(NrrdFiles, RandomMutationsNeverCrash) {
  const std::string data = bytes_of(kI16Values, false);
  write("s0.raw", data.substr(0, 12));
  write("s1.raw", data.substr(12, 12));
  write("q1.raw", data.substr(0, 12));
  write("q2.raw", data.substr(12, 12));
  const std::string seeds[] = {
      small_header("encoding: raw\nspacings: 1 2 3\n\n") + data,
      small_header("encoding: gzip\nspace: RAS\nspace directions: (1,0,0) (0,2,0) (0,0,3)\nspace origin: (1,2,3)\n\n") +
          gzip_compress(data),
      "NRRD0004\ntype: short\ndimension: 3\nsizes: 2 3 2\nendian: big\nencoding: raw\nbyte skip: 2\n\n\xff\xff" +
          bytes_of(kI16Values, true),
      small_header("encoding: raw\ndata file: LIST\ns0.raw\ns1.raw\n"),
      small_header("encoding: raw\ndata file: q%d.raw 1 2 1\n"),
  };
  std::mt19937 rng(20240612);
  int ok = 0, errors = 0;
  for (int i = 0; i < 2000; ++i) {
    const std::string bytes = mutate(seeds[static_cast<std::size_t>(i) % std::size(seeds)], rng);
    const std::string p = write("m.nrrd", bytes);
    auto r = load_nrrd(p);
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
  // Both outcomes occur (the loader is strict: repeated fields and any size mismatch are errors).
  EXPECT_GT(ok, 50);
  EXPECT_GT(errors, 100);
}

}  // namespace
}  // namespace lancet::volume
