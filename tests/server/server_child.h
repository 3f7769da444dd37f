// hvdb-server as a child process for the failover tests, which kill, pause and restart several
// servers on one data directory or RADOS pool: unlike server_process.h (one server on a data
// directory, started by its constructor), any data arguments, its log kept for the failure
// message, a Unix socket of its own, and restartable. Start returns "" or why it did not come up.
#ifndef HVDB_TESTS_SERVER_SERVER_CHILD_H_
#define HVDB_TESTS_SERVER_SERVER_CHILD_H_

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

namespace hvdb::testing {

class ServerChild {
 public:
  // `args`: what says where the data is (e.g. {"--store", S, "--data", D} or {"--data", DIR,
  // "--follow"}); listen addresses are added here.
  ServerChild(std::string name, std::vector<std::string> args, std::string work)
      : name_(std::move(name)), args_(std::move(args)), work_(std::move(work)) {}
  ~ServerChild() { Kill(SIGTERM); }
  ServerChild(const ServerChild&) = delete;
  ServerChild& operator=(const ServerChild&) = delete;

  std::string Start() {
    const std::string tag = name_ + std::to_string(++starts_);
    const std::string port_file = work_ + "/port-" + tag;
    log_ = work_ + "/server-" + tag + ".log";
    std::vector<std::string> argv = {HVDB_SERVER_PATH};
    argv.insert(argv.end(), args_.begin(), args_.end());
    for (const std::string& a : {std::string("--listen"), std::string("127.0.0.1:0"),
                                 std::string("--listen"), "unix:" + work_ + "/s-" + tag,
                                 std::string("--port-file"), port_file}) {
      argv.push_back(a);
    }
    pid_ = fork();
    if (pid_ == 0) {
      int fd = ::open(log_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      dup2(fd, 1);
      dup2(fd, 2);
      std::vector<char*> cargv;
      for (std::string& a : argv) cargv.push_back(a.data());
      cargv.push_back(nullptr);
      execv(cargv[0], cargv.data());
      _exit(127);
    }
    for (int i = 0; i < 200; ++i) {
      int st;
      if (waitpid(pid_, &st, WNOHANG) == pid_) {
        pid_ = -1;
        return Log();
      }
      std::ifstream pf(port_file);
      if (pf >> port_) return "";
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return "no port file after 20 s";
  }
  // Sends `sig` and reaps the child; its wait status (-1 if none was running).
  int Kill(int sig) {
    int st = -1;
    if (pid_ > 0) {
      kill(pid_, sig);
      waitpid(pid_, &st, 0);
      pid_ = -1;
    }
    return st;
  }
  void Signal(int sig) { kill(pid_, sig); }
  std::string Address() const { return "127.0.0.1:" + std::to_string(port_); }
  std::string Log() const {
    std::ifstream in(log_);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  }

 private:
  std::string name_;
  std::vector<std::string> args_;
  std::string work_, log_;
  pid_t pid_ = -1;
  int port_ = 0;
  int starts_ = 0;
};

// Polls `done` every 100 ms until it holds or `limit` passes; whether it held.
inline bool WaitUntil(std::chrono::milliseconds limit, const std::function<bool()>& done) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (!done()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return true;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_SERVER_SERVER_CHILD_H_
