// Running the `clothdb` executable built next to the tests (CLOTHDB_EXE, set by
// tests/CMakeLists.txt): without a shell, so arguments need no quoting, with stdout and stderr
// into one log file.
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <string>
#include <vector>

#include "support/temp_dir.hpp"

extern char** environ;

namespace clothdb::test {

inline const std::string kClothdbExe = CLOTHDB_EXE;

// Starts `clothdb args...` with stdout and stderr appended to `log` (stderr to `err_log` instead
// when one is given); returns its pid.
// `cwd` (optional): the folder it runs in.
inline pid_t start_clothdb(const std::vector<std::string>& args, const std::string& log,
                           bool append = true, const std::string& err_log = "",
                           const std::string& cwd = "") {
  std::vector<std::string> all = {kClothdbExe};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(),
                                   O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC), 0644);
  if (err_log.empty())
    posix_spawn_file_actions_adddup2(&actions, 1, 2);
  else
    posix_spawn_file_actions_addopen(&actions, 2, err_log.c_str(),
                                     O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC), 0644);
  if (!cwd.empty()) posix_spawn_file_actions_addchdir_np(&actions, cwd.c_str());
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, kClothdbExe.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  EXPECT_EQ(rc, 0) << "cannot start " << kClothdbExe;
  return rc == 0 ? pid : -1;
}

struct CliResult {
  int code = -1;       // exit code; -1: it did not exit (killed by a signal, or never started)
  std::string output;  // stdout and stderr
};

// Waits for a started run and returns its exit code and everything it printed to `log`.
inline CliResult wait_clothdb(pid_t pid, const std::string& log) {
  CliResult r;
  int status = 0;
  if (pid > 0 && waitpid(pid, &status, 0) == pid && WIFEXITED(status)) r.code = WEXITSTATUS(status);
  r.output = read_text(log);
  return r;
}

// Runs `clothdb args...` to the end, its output logged to `log` (overwritten).
inline CliResult run_clothdb(const std::vector<std::string>& args, const std::string& log) {
  return wait_clothdb(start_clothdb(args, log, false), log);
}

// The same, run in the folder `cwd`.
inline CliResult run_clothdb_in(const std::string& cwd, const std::vector<std::string>& args,
                                const std::string& log) {
  return wait_clothdb(start_clothdb(args, log, false, "", cwd), log);
}

// Arguments split at spaces (for arguments without spaces of their own).
inline std::vector<std::string> split_arguments(const std::string& line) {
  std::vector<std::string> args;
  std::string word;
  for (char c : line + " ") {
    if (c != ' ') {
      word += c;
    } else if (!word.empty()) {
      args.push_back(word);
      word.clear();
    }
  }
  return args;
}

inline CliResult run_clothdb(const std::string& line, const std::string& log) {
  return run_clothdb(split_arguments(line), log);
}

}  // namespace clothdb::test
