// Expedited SDO: the byte vectors of CiA 301, both directions, and what is not an answer.

#include "device/canopen/sdo.hpp"

#include <gtest/gtest.h>

#include <array>

namespace lancet::device::canopen {
namespace {

using Bytes = std::array<std::uint8_t, 8>;

TEST(CanopenSdo, DownloadRequestsOfEachSize) {
  // 0x6076:00 = 91 (4 bytes) to node 3: 23 76 60 00 5B 00 00 00 on 0x603.
  const Frame four = sdo_download_request(3, 0x6076, 0, 91, 4);
  EXPECT_EQ(four.cob_id, 0x603u);
  EXPECT_EQ(four.len, 8);
  EXPECT_EQ(four.data, (Bytes{0x23, 0x76, 0x60, 0x00, 0x5B, 0x00, 0x00, 0x00}));
  EXPECT_EQ(sdo_download_request(3, 0x1017, 0, 250, 2).data, (Bytes{0x2B, 0x17, 0x10, 0x00, 0xFA, 0x00, 0x00, 0x00}));
  EXPECT_EQ(sdo_download_request(3, 0x60C2, 2, 0xFD, 1).data, (Bytes{0x2F, 0xC2, 0x60, 0x02, 0xFD, 0x00, 0x00, 0x00}));
  EXPECT_EQ(sdo_download_request(3, 0x1800, 1, 0x8000'0183u, 4).data, (Bytes{0x23, 0x00, 0x18, 0x01, 0x83, 0x01, 0x00, 0x80}));
}

TEST(CanopenSdo, UploadRequest) {
  const Frame f = sdo_upload_request(1, 0x6041, 0);
  EXPECT_EQ(f.cob_id, 0x601u);
  EXPECT_EQ(f.data, (Bytes{0x40, 0x41, 0x60, 0x00, 0x00, 0x00, 0x00, 0x00}));
}

TEST(CanopenSdo, ServerAnswersAndTheirDecoding) {
  // Statusword 0x0237 uploaded from node 1: 4B 41 60 00 37 02 00 00 on 0x581.
  const Frame up = sdo_upload_response(1, 0x6041, 0, 0x0237, 2);
  EXPECT_EQ(up.cob_id, 0x581u);
  EXPECT_EQ(up.data, (Bytes{0x4B, 0x41, 0x60, 0x00, 0x37, 0x02, 0x00, 0x00}));
  SdoResponse r = decode_sdo_response(up, 0x6041, 0, true);
  EXPECT_EQ(r.kind, SdoResponse::Kind::kOk);
  EXPECT_EQ(r.value, 0x0237u);

  const Frame done = sdo_download_response(1, 0x6040, 0);
  EXPECT_EQ(done.data, (Bytes{0x60, 0x40, 0x60, 0x00, 0x00, 0x00, 0x00, 0x00}));
  EXPECT_EQ(decode_sdo_response(done, 0x6040, 0, false).kind, SdoResponse::Kind::kOk);

  // 0x1000 does not exist: 80 00 10 00 00 00 02 06.
  const Frame abort = sdo_abort_response(1, 0x1000, 0, kAbortNoObject);
  EXPECT_EQ(abort.data, (Bytes{0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x02, 0x06}));
  r = decode_sdo_response(abort, 0x1000, 0, true);
  EXPECT_EQ(r.kind, SdoResponse::Kind::kAbort);
  EXPECT_EQ(r.value, 0x06020000u);
  EXPECT_STREQ(sdo_abort_text(r.value), "object does not exist in the object dictionary");
  EXPECT_STREQ(sdo_abort_text(0x12345678), "unknown abort code");
}

TEST(CanopenSdo, UploadSizesRoundTrip) {
  for (int bytes = 1; bytes <= 4; ++bytes) {
    const std::uint32_t v = 0xA1B2C3D4u >> (8 * (4 - bytes));
    const SdoResponse r = decode_sdo_response(sdo_upload_response(9, 0x2000, 3, v, bytes), 0x2000, 3, true);
    EXPECT_EQ(r.kind, SdoResponse::Kind::kOk) << bytes;
    EXPECT_EQ(r.value, v) << bytes;
  }
  // Expedited without a size: all 4 bytes.
  Frame f = sdo_upload_response(9, 0x2000, 3, 0x01020304, 4);
  f.data[0] = 0x42;
  EXPECT_EQ(decode_sdo_response(f, 0x2000, 3, true).value, 0x01020304u);
}

TEST(CanopenSdo, WhatIsNotTheAnswer) {
  const Frame up = sdo_upload_response(1, 0x6041, 0, 0x0237, 2);
  EXPECT_EQ(decode_sdo_response(up, 0x6064, 0, true).kind, SdoResponse::Kind::kNotThis) << "another object";
  EXPECT_EQ(decode_sdo_response(up, 0x6041, 1, true).kind, SdoResponse::Kind::kNotThis) << "another sub-index";
  EXPECT_EQ(decode_sdo_response(up, 0x6041, 0, false).kind, SdoResponse::Kind::kNotThis) << "an upload answer to a download";
  const Frame done = sdo_download_response(1, 0x6041, 0);
  EXPECT_EQ(decode_sdo_response(done, 0x6041, 0, true).kind, SdoResponse::Kind::kNotThis) << "a download answer to an upload";
  Frame shrt = up;
  shrt.len = 7;
  EXPECT_EQ(decode_sdo_response(shrt, 0x6041, 0, true).kind, SdoResponse::Kind::kNotThis) << "short frame";
  Frame segmented = up;
  segmented.data[0] = 0x41;  // initiate upload response, size indicated, not expedited
  EXPECT_EQ(decode_sdo_response(segmented, 0x6041, 0, true).kind, SdoResponse::Kind::kSegmented);
}

TEST(CanopenSdo, ServerReadsRequests) {
  auto rq = decode_sdo_request(sdo_download_request(3, 0x6076, 0, 91, 4));
  ASSERT_TRUE(rq);
  EXPECT_EQ(rq->kind, SdoRequest::Kind::kDownload);
  EXPECT_EQ(rq->index, 0x6076);
  EXPECT_EQ(rq->sub, 0);
  EXPECT_EQ(rq->value, 91u);
  EXPECT_EQ(rq->bytes, 4);
  rq = decode_sdo_request(sdo_download_request(3, 0x6060, 0, 10, 1));
  ASSERT_TRUE(rq);
  EXPECT_EQ(rq->bytes, 1);
  EXPECT_EQ(rq->value, 10u);
  rq = decode_sdo_request(sdo_upload_request(3, 0x1018, 1));
  ASSERT_TRUE(rq);
  EXPECT_EQ(rq->kind, SdoRequest::Kind::kUpload);
  EXPECT_EQ(rq->index, 0x1018);
  EXPECT_EQ(rq->sub, 1);

  Frame seg = sdo_download_request(3, 0x6076, 0, 91, 4);
  seg.data[0] = 0x21;  // initiate download, segmented
  EXPECT_EQ(decode_sdo_request(seg)->kind, SdoRequest::Kind::kSegmentedDownload);
  Frame other = seg;
  other.data[0] = 0x60;  // upload segment: not served
  EXPECT_EQ(decode_sdo_request(other)->kind, SdoRequest::Kind::kOther);
  Frame shrt = seg;
  shrt.len = 4;
  EXPECT_FALSE(decode_sdo_request(shrt)) << "short frame";
}

TEST(CanopenSdo, ExpeditedSize) {
  EXPECT_EQ(expedited_size(0x23), 4);
  EXPECT_EQ(expedited_size(0x27), 3);
  EXPECT_EQ(expedited_size(0x2B), 2);
  EXPECT_EQ(expedited_size(0x2F), 1);
  EXPECT_EQ(expedited_size(0x22), 4) << "no size indicated";
}

}  // namespace
}  // namespace lancet::device::canopen
