from setuptools import setup

package_name = 'pkm_recording'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        "Recording a run: the nodes' tap, the MCAP writer, the rosbag2 bag with its recovery, the recorder and player nodes."
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'recorder_node = pkm_recording.recorder_node:main',
            'player_node = pkm_recording.player_node:main',
        ],
    },
)
