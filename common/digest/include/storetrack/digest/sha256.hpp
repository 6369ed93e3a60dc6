// SHA-256 (FIPS 180-4) of byte strings and files, computed by libcrypto (OpenSSL 3 EVP): the one
// implementation of the digest in the tree.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

namespace storetrack::digest {

using Sha256 = std::array<std::uint8_t, 32>;

/// SHA-256 of `bytes`. Throws std::runtime_error only if libcrypto itself fails (no memory, no
/// SHA-256 provider): never for any input.
Sha256 sha256(std::span<const std::uint8_t> bytes);
Sha256 sha256(std::string_view text);

/// Incremental form for data that arrives in pieces (the same digest as one call over the
/// concatenation).
class Sha256Builder {
 public:
  Sha256Builder();
  ~Sha256Builder();
  Sha256Builder(const Sha256Builder&) = delete;
  Sha256Builder& operator=(const Sha256Builder&) = delete;
  void add(std::span<const std::uint8_t> bytes);
  /// The digest of everything added; the builder starts over afterwards.
  Sha256 finish();

 private:
  void* context_;  // EVP_MD_CTX, kept out of this header
};

/// Lower-case hexadecimal, 64 characters.
std::string to_hex(const Sha256& digest);

}  // namespace storetrack::digest
