#include "view/panel.hpp"

#include <fmt/format.h>
#include <imgui.h>
#include <imgui_stdlib.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace haze::view {
namespace {

using reflection::Constraint;

// Keys of a file that a live view has no use for: the animation (the viewer shows one frame of it), the
// frame range and the output list (Save image writes the EXR and the PNG).
bool skipped(const std::string& path) {
  return path == "animation" || path == "render.frames" || path == "render.outputs" || path == "render.fps";
}

std::string tooltip(const Constraint& c, std::string_view help, const std::string& path) {
  const std::string range = c.text();
  return fmt::format("{}\n{}{}", path, help, range.empty() ? "" : "\n" + range);
}

// The widget's limits from a Range (open ends just inside).
std::pair<double, double> limits(const Constraint& c, double lo_default, double hi_default) {
  if (!c.range) return {lo_default, hi_default};
  double lo = std::isfinite(c.range->lo) ? c.range->lo : lo_default;
  double hi = std::isfinite(c.range->hi) ? c.range->hi : hi_default;
  if (c.range->lo_open) lo = std::nextafter(lo, hi);
  if (c.range->hi_open) hi = std::nextafter(hi, lo);
  return {lo, hi};
}

float drag_speed(const Constraint& c, double value) {
  if (c.range && std::isfinite(c.range->lo) && std::isfinite(c.range->hi))
    return float((c.range->hi - c.range->lo) / 300.0);
  return float(std::max(std::abs(value), 1.0) * 0.005);
}

class PanelVisitor : public reflection::Visitor<PanelVisitor> {
 public:
  PanelVisitor(std::string prefix, PanelEdit& edit, std::vector<std::string>* drawn)
      : prefix_(std::move(prefix)), edit_(edit), drawn_(drawn) {}

  template <class T>
  void visit(std::string_view name, T& value, const Constraint& c, std::string_view help) {
    const std::string path = reflection::join_path(prefix_, name);
    if (skipped(path)) return;
    if (drawn_) drawn_->push_back(path);
    ImGui::PushID(path.c_str());
    const std::string label(name);
    if (widget(label, value, c, path)) {
      edit_.changed = true;
      edit_.paths.push_back(path);
    }
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", tooltip(c, help, path).c_str());
    ImGui::PopID();
  }

 private:
  // Tree nodes start open while a test lists the paths.
  bool tree(const std::string& label) {
    if (drawn_) ImGui::SetNextItemOpen(true);
    return ImGui::TreeNode(label.c_str());
  }

  template <class S>
  bool nested(const std::string& path, S& value) {
    PanelVisitor sub(path, edit_, drawn_);
    reflect(sub, value);
    return false;  // the members record their own edits
  }

  template <class T>
  bool widget(const std::string& label, T& v, const Constraint& c, const std::string& path) {
    if constexpr (std::is_same_v<T, bool>) {
      return ImGui::Checkbox(label.c_str(), &v);
    } else if constexpr (std::is_same_v<T, int>) {
      const auto [lo, hi] = limits(c, -1e9, 1e9);
      return ImGui::DragInt(label.c_str(), &v, std::max(1.f, drag_speed(c, v)), int(lo), int(hi), "%d",
                            ImGuiSliderFlags_AlwaysClamp);
    } else if constexpr (std::is_same_v<T, uint32_t>) {
      return ImGui::InputScalar(label.c_str(), ImGuiDataType_U32, &v, nullptr, nullptr, "%u",
                                ImGuiInputTextFlags_EnterReturnsTrue);
    } else if constexpr (std::is_floating_point_v<T>) {
      const auto [lo, hi] = limits(c, -1e30, 1e30);
      float f = float(v);
      const bool changed = ImGui::DragFloat(label.c_str(), &f, drag_speed(c, v), float(lo), float(hi), "%.4g",
                                            ImGuiSliderFlags_AlwaysClamp);
      if (changed) v = T(f);
      return changed;
    } else if constexpr (std::is_same_v<T, std::string>) {
      if (c.choices) {
        bool changed = false;
        if (ImGui::BeginCombo(label.c_str(), v.c_str())) {
          for (const auto& choice : c.choices->names)
            if (ImGui::Selectable(choice.c_str(), choice == v) && choice != v) {
              v = choice;
              changed = true;
            }
          ImGui::EndCombo();
        }
        return changed;
      }
      return ImGui::InputText(label.c_str(), &v, ImGuiInputTextFlags_EnterReturnsTrue);
    } else if constexpr (std::is_same_v<T, glm::vec3>) {
      const auto [lo, hi] = limits(c, -1e30, 1e30);
      return ImGui::DragFloat3(label.c_str(), &v.x,
                               drag_speed(c, std::max({std::abs(v.x), std::abs(v.y), std::abs(v.z)})),
                               float(lo), float(hi), "%.4g", ImGuiSliderFlags_AlwaysClamp);
    } else if constexpr (std::is_same_v<T, std::vector<std::string>> || std::is_same_v<T, nlohmann::json> ||
                         std::is_same_v<T, std::optional<nlohmann::json>>) {
      // Free-form values (a procedural spec, a mesh spec): shown, edited in the file.
      std::string text = reflection::detail::write_value(v).dump();
      if (text.size() > 60) text = text.substr(0, 57) + "...";
      ImGui::TextDisabled("%s: %s", label.c_str(), text.c_str());
      return false;
    } else if constexpr (reflection::Reflectable<T>) {
      if (tree(label)) {
        nested(path, v);
        ImGui::TreePop();
      }
      return false;
    } else if constexpr (reflection::ReflectableVector<T>) {
      if (tree(fmt::format("{} ({})", label, v.size()))) {
        for (size_t i = 0; i < v.size(); ++i) {
          const std::string item = fmt::format("{}[{}]", path, i);
          ImGui::PushID(int(i));
          if (tree(fmt::format("{}[{}]", label, i))) {
            nested(item, v[i]);
            ImGui::TreePop();
          }
          ImGui::PopID();
        }
        ImGui::TreePop();
      }
      return false;
    } else if constexpr (reflection::ReflectableOptional<T>) {
      bool present = v.has_value();
      bool changed = false;
      if (ImGui::Checkbox(fmt::format("##{}", label).c_str(), &present)) {
        if (present)
          v.emplace();
        else
          v.reset();
        changed = true;
      }
      ImGui::SameLine();
      if (v) {
        if (tree(label)) {
          nested(path, *v);
          ImGui::TreePop();
        }
      } else {
        ImGui::TextDisabled("%s (absent)", label.c_str());
      }
      return changed;
    } else {
      static_assert(reflection::detail::always_false<T>, "no widget for this parameter type");
    }
  }

  std::string prefix_;
  PanelEdit& edit_;
  std::vector<std::string>* drawn_;
};

}  // namespace

PanelEdit draw_parameters(scene::Scene& s, std::vector<std::string>* drawn) {
  PanelEdit edit;
  PanelVisitor v("", edit, drawn);
  reflect(v, s);
  edit.camera_only =
      edit.changed && std::all_of(edit.paths.begin(), edit.paths.end(),
                                  [](const std::string& p) { return p.rfind("camera.", 0) == 0; });
  return edit;
}

scene::Scene check_edit(const scene::Scene& edited) {
  scene::Scene s =
      scene::from_json(scene::to_json(edited), edited.path.empty() ? "panel" : edited.path, edited.base_dir);
  s.path = edited.path;
  return s;
}

}  // namespace haze::view
