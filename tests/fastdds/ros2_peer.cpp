// A ROS 2 peer of `outlet serve ros2-bridge` on eProsima Fast DDS 2.9 (the
// middleware of rmw_fastrtps_cpp, ROS 2's default), for tests/tests/ros2_fastdds.rs.
//
// It plays a camera driver and a consumer of the results, as tests/ros2_interop.py
// does with Cyclone DDS:
// - for each scene of SCENES_DIR (prepared by the Rust test: raw pixels, a raw
//   cloud, the camera) it publishes sensor_msgs/PointCloud2, CameraInfo and
//   Image with one fresh header.stamp, again every --period seconds with a new
//   stamp until the bridge answers on /outlet/holes with one of those stamps;
// - it reads geometry_msgs/PoseArray (/outlet/holes), PoseStamped
//   (/outlet/pose), tf2_msgs/TFMessage (/tf), vision_msgs/Detection3DArray
//   (/outlet/detections) and diagnostic_msgs/DiagnosticArray (/diagnostics),
//   decoded with its own declarations of the types (ros2_msgs.hpp), and writes
//   what came for each scene's answer as one JSON line to --out; the Rust test
//   checks those values against the ground truth;
// - with --debug-image it also reads the bridge's debug image
//   (/outlet/debug_image, sensor_msgs/Image rgb8: 0.9-6 MB, a fragmented
//   sample) of one of each scene's frames, and writes its pixels beside --out
//   (OUT.STEM.debug.rgb) for the Rust test to compare with the frame sent.
// With --bench SECONDS it instead publishes the first scene's Image and
// CameraInfo at --fps for 3 s of warm-up and SECONDS measured, and prints the
// measured window's first and last stamps and its count; the Rust side
// measures when each frame reaches shared memory.
//
// LOOPBACK ONLY: the participant takes its QoS from the Fast DDS XML profile
// in FASTRTPS_DEFAULT_PROFILES_FILE (tests/dds/fastdds-loopback.xml), and this
// program refuses to run (exit 2) unless that profile confines it to 127.0.0.1:
// builtin transports off, UDPv4 transports whitelisting 127.0.0.1 only,
// unicast discovery and data locators on 127.0.0.1, no multicast locators.
//
// Exit status: 0 when every scene was answered (the values are the Rust
// test's to judge), 1 otherwise, 2 for bad arguments or environment.

#include "ros2_msgs.hpp"

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

using namespace eprosima::fastdds::dds;
using eprosima::fastrtps::rtps::IPLocator;
using eprosima::fastrtps::rtps::LocatorList_t;
using Clock = std::chrono::steady_clock;

namespace {

/// The environment or the arguments do not allow a run (exit status 2).
struct Refused : std::runtime_error {
    using std::runtime_error::runtime_error;
};

struct Args {
    int domain = -1;
    std::string scenes;
    std::string out;
    double timeout_s = 60;
    double period_s = 0.2;
    double scene_gap_s = 0.5;
    std::string frame_id = "camera_optical_frame";
    bool asynchronous = true;
    double bench_s = 0;
    double fps = 30;
    std::vector<std::string> expect_diagnostics;
    bool debug_image = false;
};

std::vector<std::string> split(const std::string& text, char by) {
    std::vector<std::string> parts;
    std::stringstream in(text);
    for (std::string part; std::getline(in, part, by);) {
        if (!part.empty()) parts.push_back(part);
    }
    return parts;
}

Args parse_args(int argc, char** argv) {
    Args a;
    for (int i = 1; i < argc; ++i) {
        std::string k = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) throw Refused(k + " needs a value");
            return argv[++i];
        };
        try {
            if (k == "--domain") a.domain = std::stoi(value());
            else if (k == "--out") a.out = value();
            else if (k == "--timeout") a.timeout_s = std::stod(value());
            else if (k == "--period") a.period_s = std::stod(value());
            else if (k == "--scene-gap") a.scene_gap_s = std::stod(value());
            else if (k == "--frame-id") a.frame_id = value();
            else if (k == "--bench") a.bench_s = std::stod(value());
            else if (k == "--fps") a.fps = std::stod(value());
            else if (k == "--expect-diagnostics") a.expect_diagnostics = split(value(), ',');
            else if (k == "--debug-image") a.debug_image = true;
            else if (k == "--publish-mode") {
                std::string mode = value();
                if (mode != "sync" && mode != "async") throw Refused("--publish-mode sync|async, not " + mode);
                a.asynchronous = mode == "async";
            } else if (!k.empty() && k[0] != '-' && a.scenes.empty()) a.scenes = k;
            else throw Refused("unknown argument " + k);
        } catch (const std::invalid_argument&) {
            throw Refused(k + ": not a number");
        } catch (const std::out_of_range&) {
            throw Refused(k + ": out of range");
        }
    }
    if (a.domain < 0 || a.domain > 232) throw Refused("--domain 0..232 is required");
    if (a.scenes.empty()) throw Refused("SCENES_DIR is required");
    if (a.bench_s <= 0 && a.out.empty()) throw Refused("--out FILE is required (or --bench SECONDS)");
    if (!(a.fps > 0) || !(a.period_s > 0)) throw Refused("--fps and --period must be positive");
    return a;
}

// ---------------------------------------------------------------------------
// Loopback confinement: the default participant QoS, from the XML profile.

std::string show_locators(const LocatorList_t& list) {
    std::string s;
    for (const auto& l : list) s += (s.empty() ? "" : ", ") + IPLocator::toIPv4string(l);
    return s.empty() ? "none" : s;
}

/// The default participant QoS, checked to use 127.0.0.1 only; the reason otherwise.
DomainParticipantQos loopback_qos() {
    const char* file = std::getenv("FASTRTPS_DEFAULT_PROFILES_FILE");
    if (file == nullptr || *file == '\0') {
        throw Refused(
            "FASTRTPS_DEFAULT_PROFILES_FILE is not set: this peer may only send traffic to loopback addresses; "
            "set it to <repo>/tests/dds/fastdds-loopback.xml");
    }
    auto* factory = DomainParticipantFactory::get_instance();
    if (factory->load_profiles() != ReturnCode_t::RETCODE_OK) {
        throw Refused(std::string(file) + ": Fast DDS could not load the XML profiles");
    }
    DomainParticipantQos qos;
    factory->get_default_participant_qos(qos);
    std::vector<std::string> wrong;
    if (qos.transport().use_builtin_transports) wrong.push_back("useBuiltinTransports is not false");
    if (qos.transport().user_transports.empty()) wrong.push_back("no user transport");
    for (const auto& t : qos.transport().user_transports) {
        auto udp = std::dynamic_pointer_cast<eprosima::fastdds::rtps::UDPv4TransportDescriptor>(t);
        if (!udp) {
            wrong.push_back("a transport that is not UDPv4");
        } else if (udp->interfaceWhiteList != std::vector<std::string>{"127.0.0.1"}) {
            wrong.push_back("a UDPv4 transport whose interfaceWhiteList is not exactly 127.0.0.1");
        }
    }
    const auto& wire = qos.wire_protocol();
    auto only_loopback = [&](const LocatorList_t& list, const char* what, bool required) {
        if (list.empty() && required) wrong.push_back(std::string(what) + " is empty");
        for (const auto& l : list) {
            if (IPLocator::toIPv4string(l) != "127.0.0.1") {
                wrong.push_back(std::string(what) + " has " + IPLocator::toIPv4string(l));
            }
        }
    };
    only_loopback(wire.builtin.metatrafficUnicastLocatorList, "metatrafficUnicastLocatorList", true);
    only_loopback(wire.builtin.initialPeersList, "initialPeersList", true);
    only_loopback(wire.default_unicast_locator_list, "defaultUnicastLocatorList", true);
    if (!wire.builtin.metatrafficMulticastLocatorList.empty()) {
        wrong.push_back("metatrafficMulticastLocatorList is " + show_locators(wire.builtin.metatrafficMulticastLocatorList));
    }
    if (!wire.default_multicast_locator_list.empty()) {
        wrong.push_back("defaultMulticastLocatorList is " + show_locators(wire.default_multicast_locator_list));
    }
    if (!wrong.empty()) {
        std::string why;
        for (const auto& w : wrong) why += "; " + w;
        throw Refused(std::string(file) + ": the default participant profile must confine Fast DDS to 127.0.0.1" + why);
    }
    return qos;
}

// ---------------------------------------------------------------------------
// Scenes, as the Rust test writes them: SCENES_DIR/scenes.txt lists the stems;
// STEM.txt has `key value...` lines; STEM.pixels holds height x step bytes,
// STEM.cloud the cloud's data (16-byte points: float32 x, y, z, intensity).

struct Scene {
    std::string stem;
    uint32_t width = 0, height = 0, step = 0;
    std::string encoding;
    std::array<double, 9> k{};
    std::vector<double> d;
    std::vector<uint8_t> pixels;
    std::vector<uint8_t> cloud;
};

std::vector<uint8_t> read_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Refused(path + ": cannot read");
    return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::vector<Scene> load_scenes(const std::string& dir) {
    std::vector<Scene> scenes;
    std::ifstream list(dir + "/scenes.txt");
    if (!list) throw Refused(dir + "/scenes.txt: cannot read");
    for (std::string stem; std::getline(list, stem);) {
        if (stem.empty()) continue;
        Scene s;
        s.stem = stem;
        std::string path = dir + "/" + stem + ".txt";
        std::ifstream in(path);
        if (!in) throw Refused(path + ": cannot read");
        for (std::string line; std::getline(in, line);) {
            std::istringstream words(line);
            std::string key;
            words >> key;
            if (key == "width") words >> s.width;
            else if (key == "height") words >> s.height;
            else if (key == "step") words >> s.step;
            else if (key == "encoding") words >> s.encoding;
            else if (key == "k") {
                for (double& v : s.k) words >> v;
            } else if (key == "d") {
                for (double v; words >> v;) s.d.push_back(v);
                words.clear();
            }
            if (words.fail()) throw Refused(path + ": bad line: " + line);
        }
        s.pixels = read_file(dir + "/" + stem + ".pixels");
        s.cloud = read_file(dir + "/" + stem + ".cloud");
        if (s.width == 0 || s.height == 0 || s.pixels.size() != size_t(s.height) * s.step) {
            throw Refused(stem + ": " + std::to_string(s.pixels.size()) + " bytes of pixels for " +
                          std::to_string(s.width) + "x" + std::to_string(s.height) + ", step " + std::to_string(s.step));
        }
        if (s.cloud.size() % 16 != 0) throw Refused(stem + ".cloud: not 16-byte points");
        scenes.push_back(std::move(s));
    }
    if (scenes.empty()) throw Refused(dir + "/scenes.txt: no scenes");
    return scenes;
}

// ---------------------------------------------------------------------------
// Messages out of a scene.

ros2::Time stamp_of(int64_t ns) {
    ros2::Time t;
    t.sec = static_cast<int32_t>(ns / 1000000000);
    t.nanosec = static_cast<uint32_t>(ns % 1000000000);
    return t;
}

int64_t now_ns() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
        .count();
}

using StampKey = std::pair<int32_t, uint32_t>;
StampKey key_of(const ros2::Time& t) { return {t.sec, t.nanosec}; }

ros2::CameraInfo camera_info_msg(const Scene& s, const ros2::Header& h) {
    ros2::CameraInfo m;
    m.header = h;
    m.height = s.height;
    m.width = s.width;
    m.distortion_model = "plumb_bob";
    m.d = s.d;
    m.k = s.k;
    m.r = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    m.p = {s.k[0], s.k[1], s.k[2], 0, s.k[3], s.k[4], s.k[5], 0, s.k[6], s.k[7], s.k[8], 0};
    return m;
}

ros2::PointCloud2 cloud_msg(const Scene& s, const ros2::Header& h) {
    ros2::PointCloud2 m;
    m.header = h;
    m.height = 1;
    m.width = static_cast<uint32_t>(s.cloud.size() / 16);
    const char* names[] = {"x", "y", "z", "intensity"};
    for (uint32_t i = 0; i < 4; ++i) {
        m.fields.push_back(ros2::PointField{names[i], 4 * i, ros2::PointField::FLOAT32, 1});
    }
    m.point_step = 16;
    m.row_step = 16 * m.width;
    m.data = s.cloud;
    m.is_dense = false;
    return m;
}

ros2::Image image_msg(const Scene& s, const ros2::Header& h) {
    ros2::Image m;
    m.header = h;
    m.height = s.height;
    m.width = s.width;
    m.encoding = s.encoding;
    m.step = s.step;
    m.data = s.pixels;
    return m;
}

// ---------------------------------------------------------------------------
// JSON out.

std::string json_string(const std::string& s) {
    std::string o = "\"";
    for (char c : s) {
        if (c == '"' || c == '\\') o += std::string("\\") + c;
        else if (static_cast<unsigned char>(c) < 0x20) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\u%04x", c);
            o += buf;
        } else o += c;
    }
    return o + "\"";
}

std::string num(double v) {
    if (!std::isfinite(v)) return "null";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

template <class It> std::string nums(It begin, It end) {
    std::string o = "[";
    for (auto it = begin; it != end; ++it) o += (it == begin ? "" : ",") + num(*it);
    return o + "]";
}

std::string json(const ros2::Time& t) { return "[" + std::to_string(t.sec) + "," + std::to_string(t.nanosec) + "]"; }

std::string json(const ros2::Header& h) {
    return "{\"frame_id\":" + json_string(h.frame_id) + ",\"stamp\":" + json(h.stamp) + "}";
}

/// position x, y, z, then orientation x, y, z, w.
std::string json(const ros2::Pose& p) {
    const double v[] = {p.position.x,    p.position.y,    p.position.z,   p.orientation.x,
                        p.orientation.y, p.orientation.z, p.orientation.w};
    return nums(std::begin(v), std::end(v));
}

std::string json(const ros2::PoseArray& m) {
    std::string poses;
    for (const auto& p : m.poses) poses += (poses.empty() ? "" : ",") + json(p);
    return "{\"header\":" + json(m.header) + ",\"poses\":[" + poses + "]}";
}

std::string json(const ros2::PoseStamped& m) {
    return "{\"header\":" + json(m.header) + ",\"pose\":" + json(m.pose) + "}";
}

std::string json(const ros2::TFMessage& m) {
    std::string o;
    for (const auto& t : m.transforms) {
        const auto& tr = t.transform;
        const double v[] = {tr.translation.x, tr.translation.y, tr.translation.z, tr.rotation.x,
                            tr.rotation.y,    tr.rotation.z,    tr.rotation.w};
        o += (o.empty() ? "" : ",") + std::string("{\"header\":") + json(t.header) +
             ",\"child_frame_id\":" + json_string(t.child_frame_id) + ",\"transform\":" + nums(std::begin(v), std::end(v)) +
             "}";
    }
    return "{\"transforms\":[" + o + "]}";
}

std::string json(const ros2::Detection3DArray& m) {
    std::string detections;
    for (const auto& d : m.detections) {
        std::string results;
        for (const auto& r : d.results) {
            results += (results.empty() ? "" : ",") + std::string("{\"class_id\":") +
                       json_string(r.hypothesis.class_id) + ",\"score\":" + num(r.hypothesis.score) +
                       ",\"pose\":" + json(r.pose.pose) + ",\"covariance\":" +
                       nums(r.pose.covariance.begin(), r.pose.covariance.end()) + "}";
        }
        const double size[] = {d.bbox.size.x, d.bbox.size.y, d.bbox.size.z};
        detections += (detections.empty() ? "" : ",") + std::string("{\"header\":") + json(d.header) +
                      ",\"id\":" + json_string(d.id) + ",\"results\":[" + results + "],\"bbox_center\":" +
                      json(d.bbox.center) + ",\"bbox_size\":" + nums(std::begin(size), std::end(size)) + "}";
    }
    return "{\"header\":" + json(m.header) + ",\"detections\":[" + detections + "]}";
}

std::string json(const ros2::DiagnosticStatus& s) {
    std::string values;
    for (const auto& kv : s.values) values += (values.empty() ? "" : ",") + json_string(kv.key) + ":" + json_string(kv.value);
    return "{\"level\":" + std::to_string(s.level) + ",\"name\":" + json_string(s.name) +
           ",\"message\":" + json_string(s.message) + ",\"hardware_id\":" + json_string(s.hardware_id) +
           ",\"values\":{" + values + "}}";
}

// ---------------------------------------------------------------------------
// DDS endpoints.

/// ROS 2 topic `/x/y` is DDS topic `rt/x/y`.
std::string dds_topic(const std::string& ros_name) { return "rt" + ros_name; }

struct Endpoints {
    DomainParticipant* participant = nullptr;
    Publisher* publisher = nullptr;
    Subscriber* subscriber = nullptr;
    std::vector<std::pair<std::string, DataWriter*>> writers;
    std::vector<std::pair<std::string, DataReader*>> readers;

    template <class M> Topic* topic(const std::string& ros_name) {
        TypeSupport type(new ros2::RosType<M>());
        if (type.register_type(participant) != ReturnCode_t::RETCODE_OK) {
            throw std::runtime_error(std::string("registering ") + M::name);
        }
        Topic* t = participant->create_topic(dds_topic(ros_name), M::name, TOPIC_QOS_DEFAULT);
        if (t == nullptr) throw std::runtime_error("topic " + ros_name);
        return t;
    }

    template <class M> DataWriter* writer(const std::string& ros_name, bool reliable, bool asynchronous) {
        DataWriterQos q = publisher->get_default_datawriter_qos();
        // What camera drivers publish with ("sensor data": best-effort) or a reliable publisher.
        q.reliability().kind = reliable ? RELIABLE_RELIABILITY_QOS : BEST_EFFORT_RELIABILITY_QOS;
        q.durability().kind = VOLATILE_DURABILITY_QOS;
        q.history().kind = KEEP_LAST_HISTORY_QOS;
        q.history().depth = 5;
        q.publish_mode().kind = asynchronous ? ASYNCHRONOUS_PUBLISH_MODE : SYNCHRONOUS_PUBLISH_MODE;
        DataWriter* w = publisher->create_datawriter(topic<M>(ros_name), q);
        if (w == nullptr) throw std::runtime_error("writer of " + ros_name);
        writers.emplace_back(ros_name, w);
        return w;
    }

    template <class M> DataReader* reader(const std::string& ros_name, int depth) {
        DataReaderQos q = subscriber->get_default_datareader_qos();
        // What rclcpp subscribes with by default (and tf2_ros for /tf, depth 100).
        q.reliability().kind = RELIABLE_RELIABILITY_QOS;
        q.durability().kind = VOLATILE_DURABILITY_QOS;
        q.history().kind = KEEP_LAST_HISTORY_QOS;
        q.history().depth = depth;
        DataReader* r = subscriber->create_datareader(topic<M>(ros_name), q);
        if (r == nullptr) throw std::runtime_error("reader of " + ros_name);
        readers.emplace_back(ros_name, r);
        return r;
    }

    /// What has not matched yet.
    std::vector<std::string> unmatched() const {
        std::vector<std::string> out;
        for (const auto& [name, w] : writers) {
            PublicationMatchedStatus s;
            w->get_publication_matched_status(s);
            if (s.current_count == 0) out.push_back("no reader of " + dds_topic(name));
        }
        for (const auto& [name, r] : readers) {
            SubscriptionMatchedStatus s;
            r->get_subscription_matched_status(s);
            if (s.current_count == 0) out.push_back("no writer of " + dds_topic(name));
        }
        return out;
    }

    ~Endpoints() {
        if (participant != nullptr) {
            participant->delete_contained_entities();
            DomainParticipantFactory::get_instance()->delete_participant(participant);
        }
    }
};

template <class M> std::vector<M> take_all(DataReader* r) {
    std::vector<M> out;
    M m;
    SampleInfo info;
    while (r->take_next_sample(&m, &info) == ReturnCode_t::RETCODE_OK) {
        if (info.valid_data) out.push_back(m);
    }
    return out;
}

/// Everything the bridge sent, the first of each stamp.
struct Inbox {
    DataReader *holes, *pose, *tf, *detections, *diagnostics;
    DataReader* debug_image;  // or null
    std::map<StampKey, std::pair<ros2::PoseArray, Clock::time_point>> holes_by_stamp;
    std::map<StampKey, ros2::PoseStamped> pose_by_stamp;
    std::map<StampKey, ros2::TFMessage> tf_by_stamp;  // by the first transform's stamp
    std::map<StampKey, ros2::Detection3DArray> detections_by_stamp;
    std::map<std::string, ros2::DiagnosticStatus> diagnostics_by_name;
    std::map<StampKey, ros2::Image> debug_image_by_stamp;

    void drain() {
        auto now = Clock::now();
        for (auto& m : take_all<ros2::PoseArray>(holes)) holes_by_stamp.emplace(key_of(m.header.stamp), std::make_pair(m, now));
        for (auto& m : take_all<ros2::PoseStamped>(pose)) pose_by_stamp.emplace(key_of(m.header.stamp), m);
        for (auto& m : take_all<ros2::TFMessage>(tf)) {
            if (!m.transforms.empty()) tf_by_stamp.emplace(key_of(m.transforms[0].header.stamp), m);
        }
        for (auto& m : take_all<ros2::Detection3DArray>(detections)) {
            detections_by_stamp.emplace(key_of(m.header.stamp), m);
        }
        for (auto& m : take_all<ros2::DiagnosticArray>(diagnostics)) {
            for (auto& s : m.status) diagnostics_by_name[s.name] = s;
        }
        if (debug_image != nullptr) {
            for (auto& m : take_all<ros2::Image>(debug_image)) debug_image_by_stamp.emplace(key_of(m.header.stamp), m);
        }
    }
};

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

void sleep_s(double s) { std::this_thread::sleep_for(std::chrono::duration<double>(s)); }

bool wait_for_discovery(const Endpoints& ep, double timeout_s) {
    auto start = Clock::now();
    while (seconds_since(start) < timeout_s) {
        if (ep.unmatched().empty()) {
            std::printf("discovered the bridge's endpoints in %.2f s\n", seconds_since(start));
            std::fflush(stdout);
            return true;
        }
        sleep_s(0.05);
    }
    std::string missing;
    for (const auto& m : ep.unmatched()) missing += "; " + m;
    std::printf("FAIL: the bridge was not discovered within %.0f s%s\n", timeout_s, missing.c_str());
    return false;
}

std::string show(StampKey k) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%d.%09u", k.first, k.second);
    return buf;
}

// ---------------------------------------------------------------------------
// The test: every scene until answered.

int run_test(const Args& a, const std::vector<Scene>& scenes, DataWriter* image_w,
             DataWriter* info_w, DataWriter* cloud_w, Inbox& inbox) {
    std::ofstream out(a.out);
    if (!out) throw Refused(a.out + ": cannot write");
    std::map<StampKey, std::string> published_all;  // stamp -> scene
    int64_t last_ns = 0;
    int answered = 0;
    for (size_t n = 0; n < scenes.size(); ++n) {
        const Scene& s = scenes[n];
        if (n > 0) {
            // Stamps of two scenes further apart than the pose service joins a
            // detection with a wall plane (max_plane_age_ms).
            auto gap = Clock::now();
            while (seconds_since(gap) < a.scene_gap_s) {
                inbox.drain();
                sleep_s(0.01);
            }
        }
        auto start = Clock::now();
        auto next_publish = start;
        std::map<StampKey, Clock::time_point> mine;
        int published = 0;
        bool write_failed = false;
        StampKey answer{};
        bool found = false;
        while (seconds_since(start) < a.timeout_s) {
            if (Clock::now() >= next_publish) {
                int64_t ns = std::max(now_ns(), last_ns + 1);
                last_ns = ns;
                ros2::Header h;
                h.stamp = stamp_of(ns);
                h.frame_id = a.frame_id;
                // The cloud first: its wall plane is ready when the detection of the image is.
                ros2::PointCloud2 cloud = cloud_msg(s, h);
                ros2::CameraInfo info = camera_info_msg(s, h);
                ros2::Image image = image_msg(s, h);
                write_failed |= !cloud_w->write(&cloud);
                write_failed |= !info_w->write(&info);
                auto written = Clock::now();
                write_failed |= !image_w->write(&image);
                mine[key_of(h.stamp)] = written;
                published_all[key_of(h.stamp)] = s.stem;
                ++published;
                next_publish = written + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(a.period_s));
            }
            inbox.drain();
            for (const auto& [k, _] : mine) {
                if (inbox.holes_by_stamp.count(k)) {
                    answer = k;
                    found = true;
                }
            }
            if (found) break;
            sleep_s(0.005);
        }
        if (!found) {
            std::string strangers;
            for (const auto& [k, _] : inbox.holes_by_stamp) {
                if (!published_all.count(k)) strangers += " " + show(k);
            }
            std::printf("FAIL %s: %ux%u %s; no PoseArray with the stamp of any of the %d images published in %.0f s%s%s\n",
                        s.stem.c_str(), s.width, s.height, s.encoding.c_str(), published, a.timeout_s,
                        write_failed ? " (a write() failed)" : "",
                        strangers.empty() ? "" : ("; PoseArrays with stamps never published:" + strangers).c_str());
            out << "{\"scene\":" << json_string(s.stem) << ",\"answered\":false,\"published\":" << published << "}\n";
            out.flush();
            continue;
        }
        const auto& [holes, arrived] = inbox.holes_by_stamp.at(answer);
        double latency_ms = std::chrono::duration<double, std::milli>(arrived - mine.at(answer)).count();
        // The other answers of the same frame: a little later at most.
        auto wait = Clock::now();
        while ((!inbox.pose_by_stamp.count(answer) || !inbox.tf_by_stamp.count(answer) ||
                !inbox.detections_by_stamp.count(answer)) &&
               seconds_since(wait) < 2.0) {
            sleep_s(0.005);
            inbox.drain();
        }
        std::string debug_image = "null";
        if (inbox.debug_image != nullptr) {
            // Drawn on a thread of its own, which skips a frame when busy: any of
            // this scene's frames will do.
            auto debug_wait = Clock::now();
            auto ours = [&]() {
                for (const auto& [k, m] : inbox.debug_image_by_stamp) {
                    if (mine.count(k)) return &m;
                }
                return static_cast<const ros2::Image*>(nullptr);
            };
            while (ours() == nullptr && seconds_since(debug_wait) < 5.0) {
                sleep_s(0.01);
                inbox.drain();
            }
            if (const ros2::Image* m = ours()) {
                std::string file = a.out + "." + s.stem + ".debug.rgb";
                std::ofstream pixels(file, std::ios::binary);
                pixels.write(reinterpret_cast<const char*>(m->data.data()), static_cast<std::streamsize>(m->data.size()));
                debug_image = "{\"header\":" + json(m->header) + ",\"width\":" + std::to_string(m->width) +
                              ",\"height\":" + std::to_string(m->height) + ",\"encoding\":" + json_string(m->encoding) +
                              ",\"step\":" + std::to_string(m->step) + ",\"bytes\":" + std::to_string(m->data.size()) +
                              ",\"file\":" + json_string(file) + "}";
            }
        }
        auto or_null = [](const auto& map, StampKey k) { return map.count(k) ? json(map.at(k)) : std::string("null"); };
        out << "{\"scene\":" << json_string(s.stem) << ",\"answered\":true,\"published\":" << published
            << ",\"latency_ms\":" << num(latency_ms) << ",\"stamp\":[" << answer.first << "," << answer.second
            << "],\"holes\":" << json(holes) << ",\"pose\":" << or_null(inbox.pose_by_stamp, answer)
            << ",\"tf\":" << or_null(inbox.tf_by_stamp, answer)
            << ",\"detections\":" << or_null(inbox.detections_by_stamp, answer)
            << ",\"debug_image\":" << debug_image << "}\n";
        out.flush();
        ++answered;
        std::printf("ANSWERED %s: %ux%u %s, %zu bytes of pixels; %zu poses; %d published, answered in %.0f ms%s\n",
                    s.stem.c_str(), s.width, s.height, s.encoding.c_str(), s.pixels.size(), holes.poses.size(),
                    published, latency_ms,
                    inbox.debug_image == nullptr ? ""
                    : debug_image == "null"      ? "; no debug image"
                                                 : "; a debug image came");
        std::fflush(stdout);
    }
    // Diagnostics from the heartbeats: the expected names, at most --timeout more.
    std::vector<std::string> missing;
    auto start = Clock::now();
    do {
        inbox.drain();
        missing.clear();
        for (const auto& name : a.expect_diagnostics) {
            if (!inbox.diagnostics_by_name.count(name)) missing.push_back(name);
        }
        if (!missing.empty()) sleep_s(0.05);
    } while (!missing.empty() && seconds_since(start) < a.timeout_s);
    std::string statuses;
    for (const auto& [name, status] : inbox.diagnostics_by_name) statuses += (statuses.empty() ? "" : ",") + json(status);
    out << "{\"diagnostics\":[" << statuses << "]}\n";
    std::printf("%d of %zu scenes answered; %zu diagnostic statuses\n", answered, scenes.size(),
                inbox.diagnostics_by_name.size());
    for (const auto& name : missing) std::printf("FAIL: no DiagnosticStatus named %s\n", name.c_str());
    return answered == static_cast<int>(scenes.size()) && missing.empty() ? 0 : 1;
}

// ---------------------------------------------------------------------------
// The bench: one scene's Image and CameraInfo at --fps.

int run_bench(const Args& a, const Scene& s, DataWriter* image_w, DataWriter* info_w) {
    const double warmup_s = 3.0;
    auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / a.fps));
    ros2::Image image = image_msg(s, ros2::Header{});
    ros2::CameraInfo info = camera_info_msg(s, ros2::Header{});
    image.header.frame_id = info.header.frame_id = a.frame_id;
    std::vector<double> write_ms;
    int64_t first = 0, last = 0;
    int frames = 0, failed = 0;
    auto start = Clock::now();
    auto next = start;
    while (seconds_since(start) < warmup_s + a.bench_s) {
        std::this_thread::sleep_until(next);
        next += period;
        bool measured = seconds_since(start) >= warmup_s;
        int64_t ns = now_ns();
        info.header.stamp = image.header.stamp = stamp_of(ns);
        failed += !info_w->write(&info);
        auto before = Clock::now();
        bool ok = image_w->write(&image);
        if (measured) {
            write_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - before).count());
            first = first ? first : ns;
            last = ns;
            frames += ok;
            failed += !ok;
        }
    }
    std::sort(write_ms.begin(), write_ms.end());
    auto q = [&](double p) { return write_ms.empty() ? NAN : write_ms[size_t(p * (write_ms.size() - 1))]; };
    std::printf("WINDOW %lld %lld %d\n", static_cast<long long>(first), static_cast<long long>(last), frames);
    std::printf("image %ux%u %s (%zu bytes): %d written in the window, %d write() failures; write() p50 %.3f ms, p99 %.3f ms\n",
                s.width, s.height, s.encoding.c_str(), s.pixels.size(), frames, failed, q(0.5), q(0.99));
    // Time for the last samples to leave an asynchronous writer.
    sleep_s(1.0);
    return 0;
}

int run(int argc, char** argv) {
    Args a = parse_args(argc, argv);
    DomainParticipantQos qos = loopback_qos();
    std::vector<Scene> scenes = load_scenes(a.scenes);
    std::printf("fastdds peer: Fast DDS on 127.0.0.1 only (%s), DDS domain %d, %zu scenes, %s writers\n",
                std::getenv("FASTRTPS_DEFAULT_PROFILES_FILE"), a.domain, scenes.size(),
                a.asynchronous ? "asynchronous" : "synchronous");
    std::fflush(stdout);

    Endpoints ep;
    ep.participant = DomainParticipantFactory::get_instance()->create_participant(a.domain, qos);
    if (ep.participant == nullptr) throw std::runtime_error("creating the participant");
    ep.publisher = ep.participant->create_publisher(PUBLISHER_QOS_DEFAULT);
    ep.subscriber = ep.participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    if (ep.publisher == nullptr || ep.subscriber == nullptr) throw std::runtime_error("publisher, subscriber");
    DataWriter* image_w = ep.writer<ros2::Image>("/camera/image_raw", false, a.asynchronous);
    DataWriter* info_w = ep.writer<ros2::CameraInfo>("/camera/camera_info", true, a.asynchronous);
    if (a.bench_s > 0) {
        if (!wait_for_discovery(ep, a.timeout_s)) return 1;
        return run_bench(a, scenes.front(), image_w, info_w);
    }
    DataWriter* cloud_w = ep.writer<ros2::PointCloud2>("/camera/points", true, a.asynchronous);
    Inbox inbox{
        ep.reader<ros2::PoseArray>("/outlet/holes", 100),
        ep.reader<ros2::PoseStamped>("/outlet/pose", 100),
        ep.reader<ros2::TFMessage>("/tf", 100),
        ep.reader<ros2::Detection3DArray>("/outlet/detections", 100),
        ep.reader<ros2::DiagnosticArray>("/diagnostics", 100),
        // What an image viewer subscribes with (reliable); the newest two.
        a.debug_image ? ep.reader<ros2::Image>("/outlet/debug_image", 2) : nullptr,
        {}, {}, {}, {}, {}, {},
    };
    if (!wait_for_discovery(ep, a.timeout_s)) return 1;
    return run_test(a, scenes, image_w, info_w, cloud_w, inbox);
}

}  // namespace

int main(int argc, char** argv) {
    try {
        return run(argc, argv);
    } catch (const Refused& e) {
        std::fprintf(stderr, "fastdds peer: refusing to run: %s\n", e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "fastdds peer: %s\n", e.what());
        return 1;
    }
}
