#include "storetrack/digest/sha256.hpp"

#include <openssl/evp.h>

#include <stdexcept>

namespace storetrack::digest {
namespace {

EVP_MD_CTX* as_context(void* p) {
  return static_cast<EVP_MD_CTX*>(p);
}
void check(int ok, const char* what) {
  if (ok != 1) throw std::runtime_error(std::string("libcrypto SHA-256: ") + what + " failed");
}

}  // namespace

Sha256Builder::Sha256Builder() : context_(EVP_MD_CTX_new()) {
  if (context_ == nullptr) throw std::runtime_error("libcrypto SHA-256: EVP_MD_CTX_new failed");
  check(EVP_DigestInit_ex(as_context(context_), EVP_sha256(), nullptr), "EVP_DigestInit_ex");
}

Sha256Builder::~Sha256Builder() {
  EVP_MD_CTX_free(as_context(context_));
}

void Sha256Builder::add(std::span<const std::uint8_t> bytes) {
  if (bytes.empty()) return;
  check(EVP_DigestUpdate(as_context(context_), bytes.data(), bytes.size()), "EVP_DigestUpdate");
}

Sha256 Sha256Builder::finish() {
  Sha256 out{};
  unsigned int length = 0;
  check(EVP_DigestFinal_ex(as_context(context_), out.data(), &length), "EVP_DigestFinal_ex");
  if (length != out.size()) throw std::runtime_error("libcrypto SHA-256: digest of wrong length");
  check(EVP_DigestInit_ex(as_context(context_), EVP_sha256(), nullptr), "EVP_DigestInit_ex");
  return out;
}

Sha256 sha256(std::span<const std::uint8_t> bytes) {
  Sha256Builder b;
  b.add(bytes);
  return b.finish();
}

Sha256 sha256(std::string_view text) {
  return sha256(std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(text.data()),
                                              text.size()));
}

std::string to_hex(const Sha256& digest) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string s;
  s.reserve(64);
  for (std::uint8_t b : digest) {
    s += kHex[b >> 4];
    s += kHex[b & 0xF];
  }
  return s;
}

}  // namespace storetrack::digest
