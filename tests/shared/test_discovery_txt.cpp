// The DNS-SD TXT records a scanner announces: what slscand writes, slscan discover reads back.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "slproto/discovery.hpp"

namespace {

using namespace slproto;
using ::testing::HasSubstr;

TEST(DiscoveryTxt, RoundTripsEveryField) {
  ScannerAdvert advert{"rpi", "slscand 0.2.0", 1, 2, true, false};
  const auto records = to_txt_records(advert);
  EXPECT_THAT(records, ::testing::ElementsAre("txtvers=1", "board=rpi", "version=slscand 0.2.0", "proto=1-2", "token=1",
                                              "sim=0"));
  auto back = from_txt_records(records);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->board, "rpi");
  EXPECT_EQ(back->software_version, "slscand 0.2.0");
  EXPECT_EQ(back->min_protocol, 1u);
  EXPECT_EQ(back->max_protocol, 2u);
  EXPECT_TRUE(back->token_required);
  EXPECT_FALSE(back->simulated);
}

TEST(DiscoveryTxt, LongValuesAreCutToOneDnsSdRecord) {
  ScannerAdvert advert{std::string(400, 'b'), "v", 1, 1, false, true};
  for (const auto& r : to_txt_records(advert)) EXPECT_LE(r.size(), 255u) << r.substr(0, 20);
}

TEST(DiscoveryTxt, UnknownKeysAreIgnoredAndBadOnesNamed) {
  auto later = from_txt_records({"board=bbb", "proto=2-5", "colour=blue", "sim=1"});
  ASSERT_TRUE(later.ok()) << later.error().message;
  EXPECT_EQ(later->max_protocol, 5u);
  EXPECT_TRUE(later->simulated);
  EXPECT_THAT(from_txt_records({"board=x", "proto=2"}).error().message, HasSubstr("'proto=2': proto must be MIN-MAX"));
  EXPECT_THAT(from_txt_records({"board=x", "proto=3-2"}).error().message, HasSubstr("'proto=3-2'"));
  EXPECT_THAT(from_txt_records({"board=x", "proto=0-2"}).error().message, HasSubstr("'proto=0-2'"));
  EXPECT_THAT(from_txt_records({"proto=1-2"}).error().message, HasSubstr("no board=NAME"));
  EXPECT_THAT(from_txt_records({"board=x"}).error().message, HasSubstr("no proto=MIN-MAX"));
}

}  // namespace
