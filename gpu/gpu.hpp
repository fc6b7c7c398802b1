#pragma once
// haze's GPU layer: device, buffers, images, compute pipelines, run-time shader compiler, timestamps, memory
// ledger. Knows nothing of rendering.

#include "gpu/buffer.hpp"
#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/frames.hpp"
#include "gpu/image.hpp"
#include "gpu/kernel.hpp"
#include "gpu/ledger.hpp"
#include "gpu/pipeline.hpp"
#include "gpu/pixel_layers.hpp"
#include "gpu/shader_compiler.hpp"
#include "gpu/timer.hpp"
#include "gpu/vk_struct.hpp"
