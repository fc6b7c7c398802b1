// Keyframed animation: the scene at a frame (docs/scene-format.md, "Animation"). Plain functions of the
// loaded Scene, so any frame, the previous one included, can be evaluated on its own and gives the same
// result every time.
#pragma once

#include <string>
#include <string_view>
#include <utility>

#include "reflect/params.hpp"
#include "scene/scene.hpp"

namespace haze::scene {

// The static scene at `frame`: each track's value written into its parameter, the checks of the objects
// it changed run again (directions normalised), each media[].file pattern replaced by that frame's file,
// and no animation left. Tracks hold their first key before it, so frames before 0 are fine (motion
// vectors at frame 0 can use frame -1). Reads no files: the previous frame's camera and transforms are
// scene_at_frame(s, frame - 1), a few microseconds. A scene without tracks or sequences is returned as
// is. Throws Error "<file>: frame F: <json.path>: ..." when the animated scene breaks a rule there (a
// direction interpolated through zero, a camera target reaching its position).
Scene scene_at_frame(const Scene& s, int frame);

// The frames to render, both included: render.frames, else the first to the last key of all tracks,
// else 0..0.
std::pair<int, int> frame_range(const Scene& s);

// The command line's --frames: "A:B" (both included) or "A". Throws Error "--frames TEXT: ..." on bad
// syntax, negative frames, frames above kMaxFrame, or A > B.
std::pair<int, int> parse_frames(std::string_view text);

// Seconds from frame 0 to `frame`: frame / render.fps.
double frame_time(const Scene& s, int frame);

// Tracks or sequences: does scene_at_frame change anything.
bool is_animated(const Scene& s);

// A media file with a run of '#' is a sequence; the run stands for the frame number.
bool is_sequence(std::string_view file);
// `pattern` with its run of '#' replaced by `frame`, zero-padded to the run's length like printf's
// %0Nd: "smoke_####.vdb" at 7 is "smoke_0007.vdb", at 12345 "smoke_12345.vdb", at -1 "smoke_-001.vdb".
// A pattern without '#' is returned as is.
std::string frame_file(std::string_view pattern, int frame);

// Throws Error "<file>: media[i].file: frame F: no such file: <path> ..." for the first missing file of
// a sequence medium in frames first..last. load() checks frame_range(); a caller rendering other frames
// (--frames) checks those.
void check_frame_files(const Scene& s, int first, int last);

namespace detail {
// Load-time checks (scene.cpp): every track resolves to a number or [x, y, z] of `s` with values of the
// right type and range, and every frame of frame_range(s) evaluates.
void check_animation(const Scene& s, const ReadContext& ctx);
void check_frame_files(const Scene& s, int first, int last, const ReadContext& ctx);
// "A:B" or "A" into `range`; on failure, false and why in `error`.
bool parse_frame_range(std::string_view text, std::pair<int, int>& range, std::string& error);
}  // namespace detail

}  // namespace haze::scene
