// A ROS 2 node's stand-in on ROS 2's default middleware (eProsima Fast DDS), for tests/io/test_ros2.py.
//
// Types: fastddsgen's code of ros2_msgs.idl. Topics and QoS as a ROS 2 node has them:
// DDS topic rt/<name>, reliable, keep-last, volatile (transient-local for /tf_static).
// The network: UDPv4 on 127.0.0.1 only, the peers found through unicast to 127.0.0.1
// (no multicast, no shared memory), so nothing leaves the loopback interface.
//
//   ros2_peer DOMAIN sub KIND:TOPIC [KIND:TOPIC ...]   KIND pose | diagnostics | tf
//       every sample as one JSON line {"topic": ..., "msg": {...}} on standard output
//   ros2_peer DOMAIN pub-odom TOPIC
//       publishes nav_msgs/msg/Odometry: one per standard input line
//       "sec nanosec x y qx qy qz qw"; at its end waits until every sample is acknowledged
//
// Events are JSON lines too: {"event": "matched", "topic": ..., "count": N} whenever the
// number of matched remote endpoints changes, {"event": "acked"} (pub-odom), and
// {"event": "bye"} after SIGINT/SIGTERM, on which the participant leaves the graph cleanly.

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include <csignal>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "ros2_msgsPubSubTypes.h"

using namespace eprosima::fastdds::dds;
namespace gm = geometry_msgs::msg::dds_;
namespace dm = diagnostic_msgs::msg::dds_;

static std::mutex out_mutex;

static void emit(const std::string& line)
{
  std::lock_guard<std::mutex> lock(out_mutex);
  std::fputs(line.c_str(), stdout);
  std::fputc('\n', stdout);
  std::fflush(stdout);
}

static std::string num(double v)
{
  if (!std::isfinite(v)) {
    return "null";
  }
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

static std::string str(const std::string& s)
{
  std::string out = "\"";
  for (unsigned char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += static_cast<char>(c);
    } else if (c < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\u%04x", c);
      out += buf;
    } else {
      out += static_cast<char>(c);
    }
  }
  return out + "\"";
}

static std::string header(const std_msgs::msg::dds_::Header_& h)
{
  return "{\"stamp\": {\"sec\": " + std::to_string(h.stamp().sec()) + ", \"nanosec\": " +
         std::to_string(h.stamp().nanosec()) + "}, \"frame_id\": " + str(h.frame_id()) + "}";
}

static std::string xyz(double x, double y, double z)
{
  return "{\"x\": " + num(x) + ", \"y\": " + num(y) + ", \"z\": " + num(z) + "}";
}

static std::string quat(const gm::Quaternion_& q)
{
  return "{\"x\": " + num(q.x()) + ", \"y\": " + num(q.y()) + ", \"z\": " + num(q.z()) + ", \"w\": " + num(q.w()) +
         "}";
}

static std::string json(const gm::PoseWithCovarianceStamped_& m)
{
  const auto& p = m.pose().pose();
  std::string cov = "[";
  for (size_t i = 0; i < m.pose().covariance().size(); ++i) {
    cov += (i ? ", " : "") + num(m.pose().covariance()[i]);
  }
  return "{\"header\": " + header(m.header()) + ", \"pose\": {\"pose\": {\"position\": " +
         xyz(p.position().x(), p.position().y(), p.position().z()) + ", \"orientation\": " + quat(p.orientation()) +
         "}, \"covariance\": " + cov + "]}}";
}

static std::string json(const dm::DiagnosticArray_& m)
{
  std::string out = "{\"header\": " + header(m.header()) + ", \"status\": [";
  for (size_t i = 0; i < m.status().size(); ++i) {
    const auto& s = m.status()[i];
    out += std::string(i ? ", " : "") + "{\"level\": " + std::to_string(static_cast<int>(s.level())) +
           ", \"name\": " + str(s.name()) + ", \"message\": " + str(s.message()) +
           ", \"hardware_id\": " + str(s.hardware_id()) + ", \"values\": [";
    for (size_t k = 0; k < s.values().size(); ++k) {
      out += std::string(k ? ", " : "") + "{\"key\": " + str(s.values()[k].key()) + ", \"value\": " +
             str(s.values()[k].value()) + "}";
    }
    out += "]}";
  }
  return out + "]}";
}

static std::string json(const tf2_msgs::msg::dds_::TFMessage_& m)
{
  std::string out = "{\"transforms\": [";
  for (size_t i = 0; i < m.transforms().size(); ++i) {
    const auto& t = m.transforms()[i];
    const auto& v = t.transform().translation();
    out += std::string(i ? ", " : "") + "{\"header\": " + header(t.header()) + ", \"child_frame_id\": " +
           str(t.child_frame_id()) + ", \"transform\": {\"translation\": " + xyz(v.x(), v.y(), v.z()) +
           ", \"rotation\": " + quat(t.transform().rotation()) + "}}";
  }
  return out + "]}";
}

static void matched(const std::string& topic, int count)
{
  emit("{\"event\": \"matched\", \"topic\": " + str(topic) + ", \"count\": " + std::to_string(count) + "}");
}

template <class Msg>
class Printer : public DataReaderListener {
public:
  explicit Printer(const std::string& topic) : topic_(topic) {}

  void on_subscription_matched(DataReader*, const SubscriptionMatchedStatus& s) override
  {
    matched(topic_, s.current_count);
  }

  void on_data_available(DataReader* reader) override
  {
    Msg m;
    SampleInfo info;
    while (reader->take_next_sample(&m, &info) == ReturnCode_t::RETCODE_OK) {
      if (info.valid_data) {
        emit("{\"topic\": " + str(topic_) + ", \"msg\": " + json(m) + "}");
      }
    }
  }

private:
  std::string topic_;
};

class WriterEvents : public DataWriterListener {
public:
  explicit WriterEvents(const std::string& topic) : topic_(topic) {}

  void on_publication_matched(DataWriter*, const PublicationMatchedStatus& s) override
  {
    matched(topic_, s.current_count);
  }

private:
  std::string topic_;
};

static DomainParticipant* loopback_participant(int domain)
{
  DomainParticipantQos pq;
  pq.name("pfdoa_test_peer");
  pq.transport().use_builtin_transports = false;
  auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
  udp->interfaceWhiteList.push_back("127.0.0.1");
  pq.transport().user_transports.push_back(udp);
  eprosima::fastrtps::rtps::Locator_t peer;
  eprosima::fastrtps::rtps::IPLocator::setIPv4(peer, 127, 0, 0, 1);
  pq.wire_protocol().builtin.initialPeersList.push_back(peer);
  pq.wire_protocol().builtin.metatrafficMulticastLocatorList.clear();
  return DomainParticipantFactory::get_instance()->create_participant(domain, pq);
}

static Topic* topic_of(DomainParticipant* p, const std::string& name, TopicDataType* type)
{
  TypeSupport ts(type);
  ts.register_type(p);
  return p->create_topic(name, ts.get_type_name(), TOPIC_QOS_DEFAULT);
}

static int wait_for_signal(const sigset_t& signals)
{
  int sig = 0;
  sigwait(&signals, &sig);
  return sig;
}

int main(int argc, char** argv)
{
  if (argc < 4) {
    std::fprintf(stderr, "usage: ros2_peer DOMAIN sub KIND:TOPIC... | ros2_peer DOMAIN pub-odom TOPIC\n");
    return 2;
  }
  // Every thread (Fast DDS's too) inherits the mask: the signals reach sigwait only.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  const int domain = std::atoi(argv[1]);
  const std::string mode = argv[2];
  DomainParticipant* p = loopback_participant(domain);
  if (p == nullptr) {
    std::fprintf(stderr, "ros2_peer: no participant on domain %d\n", domain);
    return 1;
  }
  std::vector<std::unique_ptr<DataReaderListener>> listeners;
  if (mode == "sub") {
    Subscriber* s = p->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    for (int i = 3; i < argc; ++i) {
      const std::string arg = argv[i];
      const size_t colon = arg.find(':');
      const std::string kind = arg.substr(0, colon), name = arg.substr(colon + 1);
      DataReaderQos rq = DATAREADER_QOS_DEFAULT;
      rq.reliability().kind = RELIABLE_RELIABILITY_QOS;
      rq.history().kind = KEEP_LAST_HISTORY_QOS;
      rq.history().depth = 100;
      Topic* t = nullptr;
      if (kind == "pose") {
        t = topic_of(p, name, new gm::PoseWithCovarianceStamped_PubSubType());
        listeners.emplace_back(new Printer<gm::PoseWithCovarianceStamped_>(name));
      } else if (kind == "diagnostics") {
        t = topic_of(p, name, new dm::DiagnosticArray_PubSubType());
        listeners.emplace_back(new Printer<dm::DiagnosticArray_>(name));
      } else if (kind == "tf") {
        t = topic_of(p, name, new tf2_msgs::msg::dds_::TFMessage_PubSubType());
        listeners.emplace_back(new Printer<tf2_msgs::msg::dds_::TFMessage_>(name));
        rq.durability().kind = TRANSIENT_LOCAL_DURABILITY_QOS;
        rq.history().depth = 1;
      } else {
        std::fprintf(stderr, "ros2_peer: unknown kind %s\n", kind.c_str());
        return 2;
      }
      s->create_datareader(t, rq, listeners.back().get());
    }
    wait_for_signal(signals);
  } else if (mode == "pub-odom") {
    const std::string name = argv[3];
    Topic* t = topic_of(p, name, new nav_msgs::msg::dds_::Odometry_PubSubType());
    Publisher* pub = p->create_publisher(PUBLISHER_QOS_DEFAULT);
    DataWriterQos wq = DATAWRITER_QOS_DEFAULT;
    wq.reliability().kind = RELIABLE_RELIABILITY_QOS;
    wq.durability().kind = VOLATILE_DURABILITY_QOS;  // a ROS 2 publisher's default
    wq.history().kind = KEEP_LAST_HISTORY_QOS;
    wq.history().depth = 5000;  // every message is kept until acknowledged (a test publishes a few hundred)
    const std::string hash = "typehash=RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0;";
    wq.user_data().data_vec(std::vector<eprosima::fastrtps::rtps::octet>(hash.begin(), hash.end()));
    WriterEvents events(name);
    DataWriter* w = pub->create_datawriter(t, wq, &events);
    std::string line;
    while (std::getline(std::cin, line)) {
      std::istringstream in(line);
      long long sec = 0;
      unsigned long long nanosec = 0;
      double x = 0, y = 0, qx = 0, qy = 0, qz = 0, qw = 1;
      if (!(in >> sec >> nanosec >> x >> y >> qx >> qy >> qz >> qw)) {
        std::fprintf(stderr, "ros2_peer: not 'sec nanosec x y qx qy qz qw': %s\n", line.c_str());
        return 2;
      }
      nav_msgs::msg::dds_::Odometry_ m;
      m.header().stamp().sec(static_cast<int32_t>(sec));
      m.header().stamp().nanosec(static_cast<uint32_t>(nanosec));
      m.header().frame_id("odom");
      m.child_frame_id("base_link");
      m.pose().pose().position().x(x);
      m.pose().pose().position().y(y);
      m.pose().pose().orientation().x(qx);
      m.pose().pose().orientation().y(qy);
      m.pose().pose().orientation().z(qz);
      m.pose().pose().orientation().w(qw);
      w->write(&m);
    }
    const bool ok = w->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(60, 0)) == ReturnCode_t::RETCODE_OK;
    emit(std::string("{\"event\": \"acked\", \"ok\": ") + (ok ? "true" : "false") + "}");
    wait_for_signal(signals);
  } else {
    std::fprintf(stderr, "ros2_peer: unknown mode %s\n", mode.c_str());
    return 2;
  }
  p->delete_contained_entities();
  DomainParticipantFactory::get_instance()->delete_participant(p);
  emit("{\"event\": \"bye\"}");
  return 0;
}
