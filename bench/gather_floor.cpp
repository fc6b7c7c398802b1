#include "bench/gather_floor.hpp"

#include <glm/gtc/packing.hpp>

namespace haze::bench {
namespace {

struct Push {
  uint32_t width, height;
};

const glm::ivec2 kTaps[7] = {{0, 0}, {2, 0}, {-2, 0}, {1, 1}, {-1, 1}, {1, -1}, {-1, -1}};

}  // namespace

GatherFloor::GatherFloor(gpu::Context& ctx, uint32_t width, uint32_t height)
    : width_(width),
      height_(height),
      records_(ctx, "bench gather records", "benchmark", uint64_t(width) * height * 16, "4 x u32"),
      sums_(ctx, "bench gather sums", "benchmark", uint64_t(width) * height * 8, "RGBA16F"),
      kernel_(ctx, gpu::KernelDecl("bench/gather.comp")
                       .buffer("records", uint64_t(width) * height * 16, 16)
                       .buffer("sums", uint64_t(width) * height * 8, 8)
                       .push(sizeof(Push))) {
  records_.fill_zero();
  bindings_.set("records", records_).set("sums", sums_);
}

void GatherFloor::upload(const std::vector<GatherRecord>& records) {
  records_.upload(records);
}

void GatherFloor::record(VkCommandBuffer cmd) const {
  Push push{width_, height_};
  auto [gx, gy] = kernel_.groups_2d(width_, height_);
  kernel_.dispatch(cmd, bindings_, &push, gx, gy);
}

std::vector<glm::vec4> GatherFloor::download() const {
  std::vector<glm::uvec2> w = sums_.download_vector<glm::uvec2>();
  std::vector<glm::vec4> out(w.size());
  for (size_t i = 0; i < w.size(); ++i)
    out[i] = glm::vec4(glm::unpackHalf2x16(w[i].x), glm::unpackHalf2x16(w[i].y));
  return out;
}

std::vector<glm::vec4> gather_floor_cpu(const std::vector<GatherRecord>& records, uint32_t width,
                                        uint32_t height) {
  std::vector<glm::vec4> out(size_t(width) * height);
  const glm::ivec2 last(int(width) - 1, int(height) - 1);
  for (uint32_t y = 0; y < height; ++y)
    for (uint32_t x = 0; x < width; ++x) {
      glm::vec4 s(0.f);
      for (const glm::ivec2& t : kTaps) {
        const glm::ivec2 q = glm::clamp(glm::ivec2(x, y) + t, glm::ivec2(0), last);
        const GatherRecord& r = records[size_t(q.y) * width + q.x];
        const glm::vec2 n = glm::unpackSnorm2x16(r.w);
        s += glm::vec4(glm::unpackHalf2x16(r.x), glm::unpackHalf2x16(r.y)) +
             glm::vec4(glm::uintBitsToFloat(r.z), n, 0.f);
      }
      out[size_t(y) * width + x] = s;
    }
  return out;
}

}  // namespace haze::bench
