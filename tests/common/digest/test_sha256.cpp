// SHA-256 against the FIPS 180-4 / NIST CAVP example vectors (published values, not computed
// here) and the incremental form against the one-shot form.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "storetrack/digest/sha256.hpp"

namespace storetrack::digest {
namespace {

TEST(Sha256, NistVectors) {
  // FIPS 180-4 examples (NIST "SHA256.pdf", CSRC example values).
  EXPECT_EQ(to_hex(sha256(std::string_view(""))),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(to_hex(sha256(std::string_view("abc"))),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(
      to_hex(sha256(std::string_view("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"))),
      "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  // One million 'a' (FIPS 180-2 appendix B.3).
  EXPECT_EQ(to_hex(sha256(std::string(1'000'000, 'a'))),
            "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

TEST(Sha256, IncrementalEqualsOneShot) {
  std::vector<std::uint8_t> data(10'007);
  for (std::size_t i = 0; i < data.size(); ++i)
    data[i] = static_cast<std::uint8_t>(i * 31 + 7);
  Sha256Builder b;
  for (std::size_t at = 0; at < data.size(); at += 997)
    b.add(std::span<const std::uint8_t>(data).subspan(
        at, std::min<std::size_t>(997, data.size() - at)));
  EXPECT_EQ(b.finish(), sha256(data));
  // The builder starts over after finish().
  b.add(std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>("abc"), 3));
  EXPECT_EQ(to_hex(b.finish()), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

}  // namespace
}  // namespace storetrack::digest
