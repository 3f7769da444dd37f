// The editing commands of `hvdb` that change points directly: edit, undo and redo; and those
// that move them: copy, cut, paste (through clipboards) and composite. select and graphcut,
// which mark points, are in select_commands.cc.
#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/common.h"
#include "client/cli/splat_files.h"
#include "formats/ply.h"

namespace hvdb::cli {
namespace {

struct EditArgs {
  std::string name;
  std::vector<double> delete_box, label_box, box, translate;
  std::optional<uint32_t> set_label, clear_label;
  uint32_t where_label = 0;
  std::string paste;
  std::optional<uint32_t> paste_frame;
  double units_scale = 1.0;
  bool skip_invalid = false;
  bool json = false;
  // To apply the operations in command-line order.
  CLI::App* cmd = nullptr;
  CLI::Option *delete_opt = nullptr, *label_opt = nullptr, *box_opt = nullptr,
              *translate_opt = nullptr, *paste_opt = nullptr;
};

struct UndoArgs {
  std::string name;
  uint64_t lsn = 0;
  bool json = false;
};

struct CopyArgs {  // copy and cut
  std::string name;
  int bit = 0;
  std::string clipboard;
  RegionArgs region;
  bool json = false;
};

struct PasteArgs {
  std::string name;
  std::string clipboard;
  std::vector<double> translate, matrix;
  bool json = false;
};

struct CompositeArgs {
  std::string name;
  std::string ply;
  double units_scale = 1.0;
  bool skip_invalid = false;
  uint32_t first_frame = 0;
  uint32_t frames = 0;
  std::string trajectory;
  bool json = false;
};

// What CLI11 fills in for these subcommands: static, so that registering them allocates
// nothing but what CLI11 does (see Context in common.h).
struct EditFamilyArgs {
  EditArgs edit;
  UndoArgs undo, redo;
  CopyArgs copy, cut;
  PasteArgs paste;
  CompositeArgs composite;
} edit_args;

// A --clipboard name: the rules of dataset names (it is a file DIR/clipboards/NAME.hvc).
std::optional<int> CheckClipboardName(const std::string& name, const std::string& command) {
  if (ValidateDatasetName(name).ok()) return std::nullopt;
  return Usage(command, "--clipboard '" + name +
                            "': a clipboard name is 1-64 letters, digits, '_', '-' or '.', not "
                            "starting with '.'");
}

// "no clipboard 'c'" said with where clipboards live.
Status ExplainClipboard(Status s, const client::Backend& b) {
  if (!s.IsNotFound() || s.message().rfind("no clipboard", 0) != 0) return s;
  return Status(s.code(), s.message() + (b.remote() ? " on " : " in ") + b.where() +
                              " ('hvdb copy' and 'hvdb cut' fill clipboards)");
}

// A trajectory file: one line 'dx,dy,dz' (metres) per frame; blank lines and lines starting
// with '#' are skipped.
Result<std::vector<std::array<double, 3>>> ReadTrajectory(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::IOError("cannot read trajectory file '" + path + "': " + std::strerror(errno));
  }
  std::vector<std::array<double, 3>> out;
  std::string line;
  for (size_t n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::array<double, 3> d{};
    const char* p = line.c_str();
    bool ok = true;
    for (size_t i = 0; i < 3 && ok; ++i) {
      char* end = nullptr;
      d[i] = std::strtod(p, &end);
      ok = end != p && std::isfinite(d[i]);
      p = end;
      while (ok && (*p == ' ' || *p == '\t')) ++p;
      if (ok && i < 2) ok = *p++ == ',';
    }
    if (!ok || *p != '\0') {
      return Status::InvalidArgument(path + ":" + std::to_string(n) +
                                     ": expected 'dx,dy,dz' (metres), got '" + line + "'");
    }
    out.push_back(d);
  }
  if (in.bad()) return Status::IOError("cannot read trajectory file '" + path + "'");
  return out;
}

int CmdEdit(Context& ctx, const EditArgs& a) {
  // Each operation, keyed by where its first option appears on the command line.
  std::vector<std::pair<size_t, Transaction::Op>> ops;
  const std::vector<CLI::Option*>& order = a.cmd->parse_order();
  auto position = [&order](std::initializer_list<const CLI::Option*> opts) {
    for (size_t i = 0; i < order.size(); ++i) {
      if (std::find(opts.begin(), opts.end(), order[i]) != opts.end()) return i;
    }
    return order.size();
  };
  auto select = [&a](const hvdb::Window& w) {
    Selection sel;
    sel.region = w;
    sel.label_mask = a.where_label;
    return sel;
  };
  int rc = kExitOk;
  if (a.delete_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(a.delete_box, "edit", "--delete-box", &rc);
    if (!w) return rc;
    ops.emplace_back(position({a.delete_opt}), Transaction::DeleteSelOp{select(*w)});
  }
  if (a.label_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(a.label_box, "edit", "--label-box", &rc);
    if (!w) return rc;
    if (!a.set_label && !a.clear_label) {
      return Usage("edit", "--label-box needs --set-label BITS or --clear-label BITS");
    }
    size_t pos = position({a.label_opt});
    if (a.set_label) ops.emplace_back(pos, Transaction::LabelOp{select(*w), *a.set_label, true});
    if (a.clear_label) {
      ops.emplace_back(pos, Transaction::LabelOp{select(*w), *a.clear_label, false});
    }
  }
  if (a.translate_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(a.box, "edit", "--box", &rc);
    if (!w) return rc;
    if (a.translate.size() != 4) return Usage("edit", "--translate takes 4 numbers DX DY DZ DT");
    Affine4 map;
    for (int i = 0; i < 4; ++i) map.c[i] = a.translate[i];
    ops.emplace_back(position({a.box_opt, a.translate_opt}),
                     Transaction::TransformOp{select(*w), map});
  }
  if (a.paste_opt->count() > 0) {
    formats::ReadOptions ro;
    ro.scale = a.units_scale;
    ro.frame = *a.paste_frame;
    ro.force_frame = true;
    ro.skip_invalid = a.skip_invalid;
    Result<std::vector<Point>> pts = ReadPlyNoting(a.paste, ro);
    if (!pts.ok()) return Fail(pts.status());
    for (Point& p : *pts) p.id = 0;  // pasted copies are new points
    ops.emplace_back(position({a.paste_opt}), Transaction::InsertOp{std::move(pts).value(), nullptr});
  }
  if (ops.empty()) {
    return Usage("edit",
                 "nothing to do: give --delete-box, --label-box, --box/--translate or --paste");
  }
  std::stable_sort(ops.begin(), ops.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  Transaction txn;
  for (auto& [pos, op] : ops) {
    std::visit(
        [&txn](auto&& o) {
          using T = std::decay_t<decltype(o)>;
          if constexpr (std::is_same_v<T, Transaction::InsertOp>) {
            txn.Insert(std::move(o.points));
          } else if constexpr (std::is_same_v<T, Transaction::DeleteSelOp>) {
            txn.DeleteSelection(std::move(o.sel));
          } else if constexpr (std::is_same_v<T, Transaction::TransformOp>) {
            txn.Transform(std::move(o.sel), o.map);
          } else if constexpr (std::is_same_v<T, Transaction::LabelOp>) {
            txn.SetLabel(std::move(o.sel), o.bits, o.set);
          }
        },
        op);
  }
  Result<CommitInfo> ci = ctx.db().Commit(a.name, txn);
  if (!ci.ok()) return Fail(ci.status());
  CommitOutput out = Committed(*ci);
  out.counts_in_text = true;
  PrintCommit(a.json, out);
  return kExitOk;
}

// undo and redo both revert a transaction; they differ in what they print.
int CmdRevert(Context& ctx, const UndoArgs& a, bool redo) {
  Result<CommitInfo> ci = ctx.db().Revert(a.name, a.lsn);
  if (!ci.ok()) return Fail(ci.status());
  CommitOutput out = Committed(*ci);
  out.fields = {{redo ? "redone" : "reverted", a.lsn}};
  out.before =
      Printf("%sreverted lsn %llu: ", redo ? "redo: " : "", static_cast<unsigned long long>(a.lsn));
  out.counts_in_text = true;
  PrintCommit(a.json, out);
  return kExitOk;
}

int CmdCopy(Context& ctx, const CopyArgs& a, bool cut) {
  const std::string cmd = cut ? "cut" : "copy";
  if (std::optional<int> rc = CheckClipboardName(a.clipboard, cmd)) return *rc;
  int rc = kExitOk;
  std::optional<Region> region;
  if (!ParseRegion(a.region, cmd, &region, &rc)) return rc;
  Result<edit::CopyResult> r = ctx.db().Copy(a.name, {a.bit, region, a.clipboard, cut});
  if (!r.ok()) return Fail(r.status());
  if (!a.json) {
    std::printf("%s %llu points with bit %d to clipboard '%s'\n", cut ? "cut" : "copied",
                static_cast<unsigned long long>(r->points), a.bit, a.clipboard.c_str());
  }
  // A copy commits nothing (lsn 0); a cut commits the deletion.
  CommitOutput out;
  out.lsn = r->lsn;
  out.fields = {{"dataset", a.name},
                {"bit", a.bit},
                {"clipboard", a.clipboard},
                {"points", r->points},
                {"cut", cut}};
  out.after = Printf(" ('hvdb undo %s %llu' puts them back)", a.name.c_str(),
                     static_cast<unsigned long long>(r->lsn));
  out.if_none = CommitOutput::IfNone::kQuiet;
  PrintCommit(a.json, out);
  return kExitOk;
}

int CmdPaste(Context& ctx, const PasteArgs& a) {
  const std::string cmd = "paste";
  if (std::optional<int> rc = CheckClipboardName(a.clipboard, cmd)) return *rc;
  Affine4 map;
  if (!a.matrix.empty()) {
    if (a.matrix.size() != 16) return Usage(cmd, "--matrix takes 16 numbers (row-major 4x4)");
    for (size_t i = 0; i < 16; ++i) map.a[i] = a.matrix[i];
  }
  if (!a.translate.empty()) {
    if (a.translate.size() != 4) return Usage(cmd, "--translate takes 4 numbers DX DY DZ DT");
    for (size_t i = 0; i < 4; ++i) map.c[i] = a.translate[i];
  }
  for (double v : map.a) {
    if (!std::isfinite(v)) return Usage(cmd, "--matrix must be finite");
  }
  for (double v : map.c) {
    if (!std::isfinite(v)) return Usage(cmd, "--translate must be finite");
  }
  Result<CommitInfo> ci = ctx.db().Paste(a.name, {a.clipboard, map});
  if (!ci.ok()) return Fail(ExplainClipboard(ci.status(), ctx.db()));
  CommitOutput out = Committed(*ci);
  out.fields = {{"dataset", a.name}, {"clipboard", a.clipboard}};
  out.before = Printf("pasted %llu points from clipboard '%s': ",
                      static_cast<unsigned long long>(ci->inserted), a.clipboard.c_str());
  PrintCommit(a.json, out);
  return kExitOk;
}

int CmdComposite(Context& ctx, const CompositeArgs& a) {
  const std::string cmd = "composite";
  if (uint64_t{a.first_frame} + a.frames - 1 > UINT32_MAX) {
    return Usage(cmd, "--first-frame " + std::to_string(a.first_frame) + " plus --frames " +
                          std::to_string(a.frames) + " passes frame 2^32-1");
  }
  // An unknown dataset is reported before any file is read.
  Result<DatasetInfo> info = ctx.db().Describe(a.name);
  if (!info.ok()) return Fail(info.status());
  std::vector<std::array<double, 3>> trajectory;
  if (!a.trajectory.empty()) {
    Result<std::vector<std::array<double, 3>>> t = ReadTrajectory(a.trajectory);
    if (!t.ok()) return Fail(t.status());
    if (t->size() != a.frames) {
      return Fail(Status::InvalidArgument("trajectory file '" + a.trajectory + "' has " +
                                          std::to_string(t->size()) + " offsets for --frames " +
                                          std::to_string(a.frames) +
                                          " (one 'dx,dy,dz' line per frame)"));
    }
    trajectory = std::move(t).value();
  }
  formats::ReadOptions ro;
  ro.scale = a.units_scale;
  ro.skip_invalid = a.skip_invalid;
  // A splat file keeps its splats' records in a Gaussian-splat dataset; another dataset
  // refuses it as import does. A point file composites into either.
  formats::GaussianFormat sniffed = SniffSplatFile(a.ply);
  if (sniffed == formats::GaussianFormat::kUnknown && info->gaussians && a.ply.ends_with(".splat")) {
    sniffed = formats::GaussianFormat::kSplat;  // no signature: its name says it
  }
  if (sniffed != formats::GaussianFormat::kUnknown && !info->gaussians) {
    return Fail(Status::InvalidArgument(
        a.ply + " is a " + formats::GaussianFormatName(sniffed) +
        " file of Gaussian splats, and '" + a.name +
        "' holds plain points: composite it into a dataset made with `hvdb create NAME --fps F "
        "--gaussians`"));
  }
  std::shared_ptr<GaussianColumns> records;
  Result<std::vector<Point>> object = std::vector<Point>{};
  if (sniffed != formats::GaussianFormat::kUnknown) {
    formats::Similarity move;
    move.scale = a.units_scale;
    records = std::make_shared<GaussianColumns>();
    std::vector<std::string> ignored;
    object = ReadSplatFrame(a.ply, 0, move, records.get(), &ignored);
  } else {
    object = ReadPlyNoting(a.ply, ro);
  }
  if (!object.ok()) return Fail(object.status());
  if (object->empty()) {
    return Fail(Status::InvalidArgument("'" + a.ply + "' has no points to composite"));
  }
  const size_t object_points = object->size();
  Result<CommitInfo> ci = ctx.db().Composite(
      a.name, {std::move(*object), a.first_frame, a.frames, trajectory, std::move(records)});
  if (!ci.ok()) return Fail(ci.status());
  const uint32_t last = a.first_frame + (a.frames - 1);
  CommitOutput out = Committed(*ci);
  out.fields = {{"dataset", a.name},
                {"object_points", object_points},
                {"first_frame", a.first_frame},
                {"last_frame", last},
                {"moving", !trajectory.empty()}};
  // Not Printf: the path may be longer than its buffer.
  out.before = "composited " + std::to_string(object_points) + " points of " + a.ply +
               " into frames " + std::to_string(a.first_frame) + ".." + std::to_string(last) +
               " (" + std::to_string(ci->inserted) + " points" +
               (trajectory.empty() ? "" : ", along the trajectory") + "): ";
  PrintCommit(a.json, out);
  return kExitOk;
}

}  // namespace

void AddEditCommands(CLI::App& app, Context& ctx) {
  EditArgs& edit = edit_args.edit;
  CLI::App* edit_cmd = app.add_subcommand(
      "edit", "Apply edits as one atomic transaction, in command-line order; prints its lsn");
  edit_cmd->add_option("name", edit.name, "Dataset")->required();
  edit.delete_opt =
      edit_cmd->add_option("--delete-box", edit.delete_box, "Delete the points in this box")
          ->expected(8);
  edit.label_opt =
      edit_cmd
          ->add_option("--label-box", edit.label_box, "Change the labels of the points in this box")
          ->expected(8);
  edit_cmd->add_option("--set-label", edit.set_label, "With --label-box: set these bits")
      ->needs(edit.label_opt);
  edit_cmd->add_option("--clear-label", edit.clear_label, "With --label-box: clear these bits")
      ->needs(edit.label_opt);
  edit.box_opt =
      edit_cmd->add_option("--box", edit.box, "Selection moved by --translate")->expected(8);
  edit.translate_opt = edit_cmd
                           ->add_option("--translate", edit.translate,
                                        "DX DY DZ DT (metres, seconds): move the --box points")
                           ->expected(4)
                           ->needs(edit.box_opt);
  edit.box_opt->needs(edit.translate_opt);
  edit_cmd->add_option("--where-label", edit.where_label,
                       "Boxes select only points with (label & MASK) != 0");
  edit.paste_opt = edit_cmd->add_option("--paste", edit.paste, "Insert the points of FILE.ply");
  edit_cmd->add_option("--frame", edit.paste_frame, "With --paste: the frame to insert into")
      ->needs(edit.paste_opt);
  edit.paste_opt->needs("--frame");
  edit_cmd->add_option("--units-scale", edit.units_scale, "With --paste: position multiplier")
      ->check(Positive());
  edit_cmd
      ->add_flag("--skip-invalid", edit.skip_invalid,
                 std::string("With --paste: ") + kSkipInvalidHelp)
      ->needs(edit.paste_opt);
  edit_cmd->add_flag("--json", edit.json, "Print JSON");
  edit.cmd = edit_cmd;
  ctx.Add(edit_cmd, [](Context& c) { return CmdEdit(c, edit_args.edit); });

  UndoArgs& undo = edit_args.undo;
  CLI::App* undo_cmd = app.add_subcommand(
      "undo", "Revert a committed edit (commits its inverse); 'hvdb redo' undoes the undo");
  undo_cmd->add_option("name", undo.name, "Dataset")->required();
  undo_cmd
      ->add_option("lsn", undo.lsn,
                   "Sequence number printed by edit, select, graphcut, cut, paste or composite")
      ->required();
  undo_cmd->add_flag("--json", undo.json, "Print JSON");
  undo_cmd->footer(
      "Undo goes through the transaction log: it reads transaction LSN's changes from the log and\n"
      "commits their inverse as a new transaction with its own lsn (printed), so the undo is\n"
      "itself atomic, durable and undoable: 'hvdb redo NAME UNDO_LSN' re-applies the edit.\n"
      "An edit is refused if a later transaction changed the same points: undo that one first.");
  ctx.Add(undo_cmd, [](Context& c) { return CmdRevert(c, edit_args.undo, /*redo=*/false); });

  UndoArgs& redo = edit_args.redo;
  CLI::App* redo_cmd = app.add_subcommand(
      "redo", "Re-apply an undone edit: reverts the undo whose lsn 'hvdb undo' printed");
  redo_cmd->add_option("name", redo.name, "Dataset")->required();
  redo_cmd->add_option("lsn", redo.lsn, "Sequence number of the undo (as printed by undo)")
      ->required();
  redo_cmd->add_flag("--json", redo.json, "Print JSON");
  redo_cmd->footer(
      "Undo and redo go through the transaction log: 'hvdb undo NAME LSN' commits the inverse of\n"
      "transaction LSN as a new transaction U; 'hvdb redo NAME U' commits the inverse of U, which\n"
      "is the original edit again, as a further transaction R (printed). Nothing is rewritten or\n"
      "forgotten: the log keeps every step, each one atomic and durable, and 'hvdb undo NAME R'\n"
      "undoes the redo. Example:\n"
      "  hvdb cut walk --bit 0 --clipboard man   # committed lsn 7\n"
      "  hvdb undo walk 7                        # committed lsn 8: the points are back\n"
      "  hvdb redo walk 8                        # committed lsn 9: cut again");
  ctx.Add(redo_cmd, [](Context& c) { return CmdRevert(c, edit_args.redo, /*redo=*/true); });
}

void AddClipboardCommands(CLI::App& app, Context& ctx) {
  for (bool cut : {false, true}) {
    CopyArgs& args = cut ? edit_args.cut : edit_args.copy;
    CLI::App* cmd = app.add_subcommand(
        cut ? "cut" : "copy",
        cut ? "Move the points carrying label bit B (in a region, if given) to a named "
              "clipboard: copies them, then deletes them in one transaction"
            : "Copy the points carrying label bit B (in a region, if given) to a named clipboard");
    cmd->add_option("name", args.name, "Dataset")->required();
    AddBit(cmd, "--bit", &args.bit, "Label bit of the points (e.g. set by select or graphcut)")
        ->required();
    cmd->add_option("--clipboard", args.clipboard,
                    "Clipboard name (letters, digits, '_', '-', '.'); replaced if it exists")
        ->required();
    AddRegionOptions(cmd, &args.region,
                     "Region (optional): only the points in it (default: all frames)");
    cmd->add_flag("--json", args.json, "Print JSON");
    cmd->footer(
        "Clipboards are files DIR/clipboards/NAME.hvc of the data directory: the embedded CLI on\n"
        "--data DIR and hvdb-server --data DIR share them, and they outlive the session. 'hvdb\n"
        "paste' inserts a clipboard's points." +
        std::string(cut ? "\nPrints the lsn of the deletion: 'hvdb undo NAME LSN' puts the points "
                          "back."
                        : ""));
    ctx.Add(
        cmd, cut ? +[](Context& c) { return CmdCopy(c, edit_args.cut, /*cut=*/true); }
                 : +[](Context& c) { return CmdCopy(c, edit_args.copy, /*cut=*/false); });
  }

  PasteArgs& paste = edit_args.paste;
  CLI::App* paste_cmd = app.add_subcommand(
      "paste", "Insert a clipboard's points as new points, moved by --matrix and --translate");
  paste_cmd->add_option("name", paste.name, "Dataset")->required();
  paste_cmd->add_option("--clipboard", paste.clipboard, "Clipboard name (see copy, cut)")
      ->required();
  paste_cmd
      ->add_option("--translate", paste.translate,
                   "DX DY DZ DT: add this (metres, seconds; DT moves them to later frames)")
      ->expected(4);
  paste_cmd
      ->add_option("--matrix", paste.matrix,
                   "16 numbers: a row-major 4x4 matrix over (x, y, z, t) applied before "
                   "--translate (default: identity)")
      ->expected(16);
  paste_cmd->add_flag("--json", paste.json, "Print JSON");
  paste_cmd->footer(
      "Each point (x, y, z, t) becomes MATRIX (x, y, z, t) + (DX, DY, DZ, DT); its frame follows\n"
      "the new t. Prints the lsn: 'hvdb undo NAME LSN' removes the pasted points again.");
  ctx.Add(paste_cmd, [](Context& c) { return CmdPaste(c, edit_args.paste); });

  CompositeArgs& composite = edit_args.composite;
  CLI::App* composite_cmd = app.add_subcommand(
      "composite",
      "Insert an object (a PLY point cloud) into consecutive frames, still or along a trajectory");
  composite_cmd->add_option("name", composite.name, "Dataset")->required();
  composite_cmd
      ->add_option("--ply", composite.ply,
                   "FILE: the object, a point PLY, or a splat file (3DGS PLY, SPZ, GLB) whose "
                   "splats keep their records in a Gaussian-splat dataset")
      ->required();
  composite_cmd
      ->add_option("--units-scale", composite.units_scale,
                   "Multiply the object's positions by this (0.01: the file is in centimetres)")
      ->capture_default_str()
      ->check(Positive());
  composite_cmd->add_option("--first-frame", composite.first_frame, "First frame F")->required();
  composite_cmd->add_option("--frames", composite.frames, "Number of frames N (> 0)")
      ->required()
      ->check(CLI::Range(1u, UINT32_MAX));
  composite_cmd->add_option(
      "--trajectory", composite.trajectory,
      "FILE.csv: one line 'dx,dy,dz' (metres) per frame, offsetting the object in frame F + i "
      "(default: it stays put)");
  composite_cmd->add_flag("--skip-invalid", composite.skip_invalid, kSkipInvalidHelp);
  composite_cmd->add_flag("--json", composite.json, "Print JSON");
  composite_cmd->footer(
      "All frames are inserted in one transaction; prints its lsn ('hvdb undo NAME LSN' removes\n"
      "the object again). Blank lines and lines starting with '#' in the trajectory are skipped.");
  ctx.Add(composite_cmd, [](Context& c) { return CmdComposite(c, edit_args.composite); });
}

}  // namespace hvdb::cli
