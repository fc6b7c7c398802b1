#include "view/ui.hpp"

#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_vulkan.h>
#include <fmt/format.h>
#include <imgui.h>

#include <algorithm>

#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/swapchain.hpp"
#include "gpu/vk_struct.hpp"
#include "view/window.hpp"

namespace haze::view {
namespace {

void check_vk(VkResult r) {
  if (r != VK_SUCCESS) throw gpu::Error(fmt::format("ImGui's Vulkan backend: VkResult {}", int(r)));
}

}  // namespace

Ui::Ui(gpu::Context& ctx, Window& window, const gpu::Swapchain& swapchain, uint32_t frames) : ctx_(ctx) {
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  io.IniFilename = nullptr;  // no imgui.ini in the working folder
  ImGui::StyleColorsDark();

  // Loads the frame's image (copied in before), draws on top, hands the image to presentation.
  VkAttachmentDescription colour{};
  colour.format = swapchain.format();
  colour.samples = VK_SAMPLE_COUNT_1_BIT;
  colour.loadOp = VK_ATTACHMENT_LOAD_OP_LOAD;
  colour.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
  colour.stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
  colour.stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
  colour.initialLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
  colour.finalLayout = VK_IMAGE_LAYOUT_PRESENT_SRC_KHR;
  VkAttachmentReference ref{0, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL};
  VkSubpassDescription sub{};
  sub.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
  sub.colorAttachmentCount = 1;
  sub.pColorAttachments = &ref;
  // The copy into the image happens before the pass loads it.
  VkSubpassDependency dep{};
  dep.srcSubpass = VK_SUBPASS_EXTERNAL;
  dep.dstSubpass = 0;
  dep.srcStageMask = VK_PIPELINE_STAGE_TRANSFER_BIT;
  dep.dstStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
  dep.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  dep.dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
  auto rp = gpu::vk_struct<VkRenderPassCreateInfo>(VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO);
  rp.attachmentCount = 1;
  rp.pAttachments = &colour;
  rp.subpassCount = 1;
  rp.pSubpasses = &sub;
  rp.dependencyCount = 1;
  rp.pDependencies = &dep;
  HAZE_VK(vkCreateRenderPass(ctx.device(), &rp, nullptr, &render_pass_));

  // One combined image sampler: the font atlas.
  VkDescriptorPoolSize size{VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 1};
  auto dp = gpu::vk_struct<VkDescriptorPoolCreateInfo>(VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO);
  dp.flags = VK_DESCRIPTOR_POOL_CREATE_FREE_DESCRIPTOR_SET_BIT;
  dp.maxSets = 1;
  dp.poolSizeCount = 1;
  dp.pPoolSizes = &size;
  HAZE_VK(vkCreateDescriptorPool(ctx.device(), &dp, nullptr, &pool_));

  ImGui_ImplGlfw_InitForVulkan(window.handle(), true);
  ImGui_ImplVulkan_InitInfo info{};
  info.Instance = ctx.instance();
  info.PhysicalDevice = ctx.physical();
  info.Device = ctx.device();
  info.QueueFamily = ctx.queue_family();
  info.Queue = ctx.queue();
  info.PipelineCache = VK_NULL_HANDLE;
  info.DescriptorPool = pool_;
  info.Subpass = 0;
  info.MinImageCount = swapchain.min_image_count();
  // ImGui's vertex buffers are reused after ImageCount frames: more than the frames in flight.
  info.ImageCount = std::max(swapchain.image_count(), frames + 1);
  info.MSAASamples = VK_SAMPLE_COUNT_1_BIT;
  info.CheckVkResultFn = check_vk;
  if (!ImGui_ImplVulkan_Init(&info, render_pass_)) throw gpu::Error("ImGui's Vulkan backend failed to start");
  ctx.submit_and_wait([](VkCommandBuffer cmd) { ImGui_ImplVulkan_CreateFontsTexture(cmd); });
  ImGui_ImplVulkan_DestroyFontUploadObjects();
  create_framebuffers(swapchain);
}

Ui::~Ui() {
  vkDeviceWaitIdle(ctx_.device());
  ImGui_ImplVulkan_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  destroy_framebuffers();
  if (pool_) vkDestroyDescriptorPool(ctx_.device(), pool_, nullptr);
  if (render_pass_) vkDestroyRenderPass(ctx_.device(), render_pass_, nullptr);
}

void Ui::create_framebuffers(const gpu::Swapchain& swapchain) {
  extent_ = swapchain.extent();
  for (uint32_t i = 0; i < swapchain.image_count(); ++i) {
    VkImageView view = swapchain.view(i);
    auto fb = gpu::vk_struct<VkFramebufferCreateInfo>(VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO);
    fb.renderPass = render_pass_;
    fb.attachmentCount = 1;
    fb.pAttachments = &view;
    fb.width = extent_.width;
    fb.height = extent_.height;
    fb.layers = 1;
    VkFramebuffer f = VK_NULL_HANDLE;
    HAZE_VK(vkCreateFramebuffer(ctx_.device(), &fb, nullptr, &f));
    framebuffers_.push_back(f);
  }
}

void Ui::destroy_framebuffers() noexcept {
  for (VkFramebuffer f : framebuffers_) vkDestroyFramebuffer(ctx_.device(), f, nullptr);
  framebuffers_.clear();
}

void Ui::recreate(const gpu::Swapchain& swapchain) {
  destroy_framebuffers();
  ImGui_ImplVulkan_SetMinImageCount(swapchain.min_image_count());
  create_framebuffers(swapchain);
}

void Ui::new_frame() {
  ImGui_ImplVulkan_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
}

void Ui::record(VkCommandBuffer cmd, uint32_t image, bool draw) {
  ImGui::Render();
  auto begin = gpu::vk_struct<VkRenderPassBeginInfo>(VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO);
  begin.renderPass = render_pass_;
  begin.framebuffer = framebuffers_.at(image);
  begin.renderArea.extent = extent_;
  vkCmdBeginRenderPass(cmd, &begin, VK_SUBPASS_CONTENTS_INLINE);
  if (draw) ImGui_ImplVulkan_RenderDrawData(ImGui::GetDrawData(), cmd);
  vkCmdEndRenderPass(cmd);
}

}  // namespace haze::view
