// `db_rows FILE`: every row of every table of a clothdb file as text (tests/support/db_rows.hpp),
// the run bookkeeping left out by name, for the shell tests (tests/mpi/run_mpi_test.sh) to compare
// two files on every table with cmp. `clothdb db dump` prints the cloth tables only.
#include <cstdio>

#include "support/db_rows.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: db_rows FILE\n");
    return 2;
  }
  const std::vector<std::string> rows =
      clothdb::test::every_row(argv[1], clothdb::test::run_bookkeeping());
  for (const std::string& row : rows) std::printf("%s\n", row.c_str());
  // every_row reports a file it cannot read through GoogleTest; here that is an exit code.
  return rows.empty() || ::testing::UnitTest::GetInstance()->ad_hoc_test_result().Failed() ? 1 : 0;
}
