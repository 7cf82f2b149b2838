// `clothdb db dump FILE`: every row of every table as text, blobs as their size and xxh64, so two
// databases can be compared with diff (database/store/dump.hpp).
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "cli_util.hpp"
#include "commands.hpp"
#include "database/store/dump.hpp"

namespace clothdb::cli {

void register_db_dump(CLI::App& app) {
  CLI::App& db = command_group(app, "db", "Inspect and check clothdb database files");
  struct Args {
    std::string file;
    std::string tables;
    std::string masked;
  };
  auto args = std::make_shared<Args>();
  CLI::App* dump = db.add_subcommand(
      "dump",
      "Prints every row of every table (blobs as size and xxh64), in key order, for comparing two "
      "databases with diff");
  dump->add_option("FILE", args->file, "clothdb database")->required()->check(CLI::ExistingFile);
  dump->add_option("--tables", args->tables,
                   "Comma-separated tables to print, in this order (default: every table the file "
                   "has, docs/DATABASE.md)");
  dump->add_option("--mask", args->masked,
                   "Comma-separated columns to print as 'masked': TABLE.COLUMN, or meta.KEY for "
                   "one meta value (e.g. run.started,run.host,meta.created,meta.forecast to compare two runs)");
  dump->callback([args] {
    db::DumpOptions options;
    if (!args->tables.empty()) options.tables = split_list(args->tables);
    if (!args->masked.empty()) options.masked = split_list(args->masked);
    db::dump_database(args->file, options, stdout);
  });
}

}  // namespace clothdb::cli
